"""Bounded input: regular files only, never more than a stated number of bytes or levels
(the problem YAML files here; every file the package reads, through ``sapga_ros.io``).

``open_regular`` opens without blocking (a FIFO or device given as a file would otherwise
freeze the reader until a writer appears) and refuses anything that is not a regular file;
``read_bounded`` reads a whole file of at most ``limit`` bytes.  Errors are ``OSError``
subclasses with a one-line message: callers add the path and their own error type.

``load_yaml`` parses YAML (safe types only) nested at most ``max_depth`` levels, without
aliases: the nesting is measured on libyaml's event stream (iterative) before anything is
built (PyYAML's composers recurse: deep nesting crashes the C one and takes seconds in the
Python one).  Errors are ``yaml.YAMLError``.
"""
from __future__ import annotations

import os
import stat
from typing import Any, BinaryIO

import yaml

MAX_YAML_DEPTH = 64


class NotRegularFile(OSError):
    """The path names a FIFO, device, socket or directory, not a regular file."""


class TooLarge(OSError):
    """The file holds more bytes than the caller accepts."""


def open_regular(path: str | os.PathLike) -> BinaryIO:
    """``path`` opened for binary reading, if it is a regular file (NotRegularFile if not)."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, 'O_CLOEXEC', 0))
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = ('a directory' if stat.S_ISDIR(mode) else 'a FIFO' if stat.S_ISFIFO(mode)
                    else 'a device or socket')
            raise NotRegularFile(f'{kind}, not a regular file')
        os.set_blocking(fd, True)
        return os.fdopen(fd, 'rb')
    except BaseException:
        os.close(fd)
        raise


def read_bounded(path: str | os.PathLike, limit: int) -> bytes:
    """The bytes of regular file ``path``; TooLarge if it holds more than ``limit``."""
    with open_regular(path) as f:
        if os.fstat(f.fileno()).st_size > limit:   # refused before a byte is read
            raise TooLarge(f'larger than {limit} bytes')
        data = f.read(limit + 1)                  # bounded even if it grows meanwhile
    if len(data) > limit:
        raise TooLarge(f'larger than {limit} bytes')
    return data


def load_yaml(text: str | bytes, max_depth: int = MAX_YAML_DEPTH) -> Any:
    """``yaml.safe_load`` of ``text`` if it nests at most ``max_depth`` levels, no aliases."""
    loader = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
    depth = 0
    for event in yaml.parse(text, Loader=loader):
        if isinstance(event, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
            depth += 1
            if depth > max_depth:
                raise yaml.YAMLError(f'nested deeper than {max_depth} levels')
        elif isinstance(event, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
            depth -= 1
        elif isinstance(event, yaml.AliasEvent):
            raise yaml.YAMLError('aliases are not accepted')
    return yaml.load(text, Loader=loader)
