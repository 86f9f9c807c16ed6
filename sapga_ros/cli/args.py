"""Argument types and output checks of the ``sapga`` command; options from config dataclasses.

``add_settings(parser, cls)`` adds one option per ``setting`` field of ``cls``
(``sapga_ros.optim.settings``): its flag, its default, its help, a type that refuses values
outside the field's bounds with one line saying what is expected; the names of the options
given on the command line are collected in ``args.given`` (``--resume`` takes the others
from the checkpoint).  ``check_output_file`` and ``check_output_dir`` refuse, before any
work, outputs that cannot be written; neither creates a folder that does not exist.
"""
from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from sapga_ros.errors import SapgaError
from sapga_ros.optim.settings import MAX_INT, Setting, described, kind_of


def _int_at_least(minimum: int, what: str, maximum: int = MAX_INT):
    """An argparse type: an integer in [minimum, maximum] (1e6-style numbers allowed)."""
    def parse(text: str) -> int:
        try:
            value = int(float(text)) if 'e' in text.lower() else int(text)
        except (ValueError, OverflowError):
            value = minimum - 1
        if not minimum <= value <= maximum:
            raise argparse.ArgumentTypeError(f'expected {what}, got {text!r}')
        return value
    return parse


positive_int = _int_at_least(1, 'a positive integer')
nonneg_int = _int_at_least(0, 'an integer >= 0')
episode_steps = _int_at_least(1, 'an integer in [1, 1000000]', 1_000_000)


def delta_value(text: str) -> float:
    """An argparse type: a goal difficulty, a finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a number, got {text!r}')
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f'expected a finite delta >= 0, got {text!r}')
    return value


def _number(s: Setting):
    """An argparse type: a finite number within the setting's bounds."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if s.problem(value, float):
            raise argparse.ArgumentTypeError(f'expected {s.expected(float)}, got {text!r}')
        return value
    return parse


class _Given(argparse.Action):
    """Store the option's value (``const`` for a flag) and add its name to ``given``."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        setattr(namespace, self.dest, self.const if self.nargs == 0 else values)
        namespace.given = frozenset(getattr(namespace, 'given', ())) | {self.dest}


def add_settings(parser: argparse.ArgumentParser, cls: type) -> None:
    """One option per ``setting`` field of ``cls`` offered on the command line (dest: the
    field's name; ``given``: the names of those on the command line)."""
    parser.set_defaults(given=frozenset())
    for f, s in described(cls):
        if not s.cli:
            continue
        kind = kind_of(f)
        how = {'dest': f.name, 'default': f.default, 'help': f'{s.help} (default {f.default})',
               'action': _Given}
        if kind is bool:
            how.update(nargs=0, const=True, help=s.help)
        elif s.choices:
            how.update(choices=s.choices)
        elif kind is int:
            low, high = s.bounds(int)
            how.update(type=_int_at_least(int(low), s.expected(int), int(high)), metavar='N')
        elif kind is float:
            how.update(type=_number(s), metavar='X')
        parser.add_argument(s.option(f.name), **how)


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
