"""Atomic file writes: a crash or a kill never leaves half a file where a good one was, and a
device, FIFO or socket at the path is never replaced by a file (``/dev/null`` as an output
stays a device).

The new content is written to a fresh temporary file (``O_EXCL``) beside the path and
renamed onto it: a symbolic link at the path is replaced, never written through.
``write_inside`` writes a file named by data (a problem name in a summary, say) into a
directory: the name must be a plain file name, so the output cannot leave the directory.
"""
from __future__ import annotations

import errno
import os
import re
import stat
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable

from sapga_ros.io.bounded import NotRegularFile


def process_umask() -> int:
    """The process's file mode creation mask, read without changing it.

    ``os.umask`` can only be read by setting it, which races with every other thread that
    creates a file meanwhile; Linux reports it in /proc/self/status.  Elsewhere the value
    is set back at once (the old race, on systems that offer nothing better).
    """
    try:
        with open('/proc/self/status', encoding='ascii') as f:
            for line in f:
                if line.startswith('Umask:'):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_atomic(path: str | os.PathLike, content: str | bytes | Callable[[BinaryIO], None]
                 ) -> Path:
    """Write ``content`` (text, bytes, or a function writing to a binary file) to ``path``
    through a temporary file in the same folder, fsync it, then rename it into place.
    ``NotRegularFile`` if something other than a regular file (or a link to one) is there."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        mode = stat.S_IFREG
    if not stat.S_ISREG(mode):
        kind = 'a directory' if stat.S_ISDIR(mode) else 'a FIFO' if stat.S_ISFIFO(mode) \
            else 'a device or socket'
        raise NotRegularFile(errno.EISDIR if stat.S_ISDIR(mode) else errno.EINVAL,
                             f'{kind}, not a regular file', str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', dir=path.parent)
    try:
        os.chmod(tmp, 0o666 & ~process_umask())  # as open() would make it, not mkstemp's 0600
        with os.fdopen(fd, 'wb') as f:
            if callable(content):
                content(f)
            else:
                f.write(content.encode('utf-8') if isinstance(content, str) else content)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


_PLAIN_NAME = re.compile(r'[A-Za-z0-9_][A-Za-z0-9._-]{0,199}')


def write_inside(directory: str | os.PathLike, name: str,
                 content: str | bytes | Callable[[BinaryIO], None]) -> Path:
    """``write_atomic`` of ``directory/name``; ValueError unless ``name`` is a plain file
    name (letters, digits, ``._-``; no separator, no leading dot)."""
    if not isinstance(name, str) or not _PLAIN_NAME.fullmatch(name) or '..' in name:
        raise ValueError(f'not a plain file name: {str(name)[:60]!r}')
    return write_atomic(Path(directory) / name, content)


def _figure_writer(fig, path: str | os.PathLike, dpi: int) -> Callable[[BinaryIO], None]:
    """Write a matplotlib figure in the format its file name says (PNG by default)."""
    fmt = Path(path).suffix[1:].lower() or 'png'
    return lambda f: fig.savefig(f, format=fmt, dpi=dpi)


def save_figure(fig, directory: str | os.PathLike, name: str, dpi: int = 100) -> Path:
    """Save a matplotlib figure as ``directory/name`` through ``write_inside``."""
    return write_inside(directory, name, _figure_writer(fig, name, dpi))


def save_figure_file(fig, path: str | os.PathLike, dpi: int = 100) -> Path:
    """Save a matplotlib figure at a path the user named, through ``write_atomic``."""
    return write_atomic(path, _figure_writer(fig, path, dpi))
