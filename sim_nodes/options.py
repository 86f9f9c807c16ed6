"""The argparse adapter of the parameter declarations (``sim_nodes/params.py``).

``add_param(parser, p)`` adds the option of one declaration: its flag, its default (a
``FromProblem`` one: None, "not given"), its help with the unit; a value the declaration
refuses ends the command with the same one line the nodes and parameter files print
(``sapga train: error: n_pop: expected an integer in [2, 1000000], got 1``, exit status 2).
``add_settings(parser, cls)`` adds one per parameter of config dataclass ``cls``; the names
of the options given on the command line are collected in ``args.given``.
"""
from __future__ import annotations

import argparse
from typing import Any

from sim_nodes.params import Param, declared


def read_text(kind: type, text: str) -> Any:
    """``text`` read as a ``kind`` number (an integer also as 1e6), else the text itself."""
    try:
        if kind is float:
            return float(text)
        if kind is int:
            number = float(text) if 'e' in text.lower() else int(text)
            return int(number) if float(number).is_integer() else text
    except (ValueError, OverflowError):
        pass
    return text


class _Given(argparse.Action):
    """Store the option's value (``const`` for a flag) if its declaration ``param`` accepts
    it, else end with the declaration's one line; add its name to ``given``."""

    def __init__(self, *args: Any, param: Param, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.param = param

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        if self.nargs == 0:
            value = self.const
        else:
            value = read_text(self.param.type, values)
            reason = self.param.reason(value)
            if reason:
                parser.error(reason)
        setattr(namespace, self.dest, value)
        namespace.given = frozenset(getattr(namespace, 'given', ())) | {self.dest}


def add_param(parser: argparse.ArgumentParser, p: Param, help: str = '') -> None:
    """The option of declaration ``p`` (dest: its name; ``help``: instead of its own)."""
    parser.set_defaults(given=frozenset())
    default = None if p.from_problem else p.default
    shown = f'default: {p.default}' if p.from_problem else f'default {p.shown_default()}'
    how: dict[str, Any] = {'dest': p.name, 'default': default, 'action': _Given,
                           'param': p, 'help': help or f'{p.text} ({shown})'}
    if p.type is bool:
        how.update(nargs=0, const=True, help=help or p.text)
    elif p.choices:
        how.update(metavar='{' + ','.join(p.choices) + '}')
    elif p.type in (int, float):
        how.update(metavar='N' if p.type is int else 'X')
    parser.add_argument(p.option(), **how)


def add_settings(parser: argparse.ArgumentParser, cls: type) -> None:
    """One option per parameter of dataclass ``cls`` offered on the command line (dest: the
    field's name; ``given``: the names of those on the command line)."""
    for p in declared(cls):
        if p.cli:
            add_param(parser, p)
