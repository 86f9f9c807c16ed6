"""Policies that are not (only) exemplars: the classical controller and the LQR catch."""
