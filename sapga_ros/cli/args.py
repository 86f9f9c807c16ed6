"""Argument types and output checks of the ``sapga`` command; options from declarations.

``add_param`` and ``add_settings`` (``sim_nodes/options.py``, re-exported here) make the
options of parameter declarations; a value a declaration refuses ends the command with the
same one line the nodes and parameter files print.  ``check_output_file`` and
``check_output_dir`` refuse, before any work, outputs that cannot be written; neither creates
a folder that does not exist.
"""
from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from sapga_ros.errors import SapgaError
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


def check_output_file(path: Path, option: str) -> None:
    """Refuse, before any work is done, an output file that cannot be written: a directory,
    a device, FIFO or socket, a file in a folder that does not exist (none is created), an
    unwritable one."""
    if path.is_dir():
        raise SapgaError(f'{option} {path}: is a directory')
    if path.exists() and not path.is_file():
        raise SapgaError(f'{option} {path}: not a regular file (a device, FIFO or socket)')
    _check_folder(path, option)
    if path.exists() and not os.access(path, os.W_OK):
        raise SapgaError(f'{option} {path}: not writable')


def check_output_dir(path: Path, option: str) -> None:
    """Refuse an output directory that cannot be used: one that is a file, or, if it does
    not exist yet, whose parent folder does not exist or cannot be written."""
    if path.exists():
        if not path.is_dir():
            raise SapgaError(f'{option} {path}: exists and is not a directory')
        if not os.access(path, os.W_OK | os.X_OK):
            raise SapgaError(f'{option} {path}: not writable')
        return
    _check_folder(path, option)


def _check_folder(path: Path, option: str) -> None:
    folder = path.parent
    if not folder.is_dir():
        what = 'is not a folder' if folder.exists() else 'does not exist'
        raise SapgaError(f'{option} {path}: {folder} {what}')
    if not os.access(folder, os.W_OK | os.X_OK):
        raise SapgaError(f'{option} {path}: folder {folder} is not writable')
