"""Analyses of the problems themselves (not of a policy): the physical limit of delta."""
