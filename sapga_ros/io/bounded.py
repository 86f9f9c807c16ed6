"""Bounded file access: regular files only, never more than a stated number of bytes.

``open_regular`` opens without blocking (a FIFO or device given as a file would otherwise
freeze the reader until a writer appears) and refuses anything that is not a regular file;
``read_bounded`` reads a whole file of at most ``limit`` bytes.  Errors are ``OSError``
subclasses with a one-line message: callers add the path and their own error type.
"""
from __future__ import annotations

import os
import stat
from typing import BinaryIO


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
        data = f.read(limit + 1)
    if len(data) > limit:
        raise TooLarge(f'larger than {limit} bytes')
    return data
