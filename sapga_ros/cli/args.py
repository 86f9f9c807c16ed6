"""Argument types and output checks of the ``sapga`` command; options from declarations.

``add_param`` and ``add_settings`` (``sim_nodes/options.py``, re-exported here) make the
options of parameter declarations; a value a declaration refuses ends the command with the
same one line the nodes and parameter files print.  ``check_output_file`` and
``check_output_dir`` (``sapga_ros/io/outputs.py``, re-exported here: the launches use them
too) refuse, before any work, outputs that cannot be written; neither creates a folder that
does not exist.
"""
from __future__ import annotations

import argparse
import math

from sapga_ros.io.outputs import check_output_dir, check_output_file
from sim_nodes.options import add_param, add_settings, read_text
from sim_nodes.params import MAX_INT

__all__ = ['add_param', 'add_settings', 'bench_steps', 'check_output_dir', 'check_output_file',
           'episode_steps', 'nonneg_int', 'nonneg_number', 'positive_int']


def _int_at_least(minimum: int, what: str, maximum: int = MAX_INT):
    """An argparse type: an integer in [minimum, maximum] (1e6-style numbers allowed)."""
    def parse(text: str) -> int:
        value = read_text(int, text)
        if not isinstance(value, int) or not minimum <= value <= maximum:
            raise argparse.ArgumentTypeError(f'expected {what}, got {text!r}')
        return value
    return parse


positive_int = _int_at_least(1, 'a positive integer')
nonneg_int = _int_at_least(0, 'an integer >= 0')
episode_steps = _int_at_least(1, 'an integer in [1, 1000000]', 1_000_000)
bench_steps = _int_at_least(20_000, 'an integer in [20000, 1000000000]', 1_000_000_000)


def nonneg_number(text: str) -> float:
    """An argparse type: a finite number >= 0."""
    value = read_text(float, text)
    if not isinstance(value, float) or not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f'expected a finite number >= 0, got {text!r}')
    return value
