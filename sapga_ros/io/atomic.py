"""Atomic file writes: a crash or a kill never leaves half a file where a good one was."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable


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
    through a temporary file in the same folder, fsync it, then rename it into place."""
    path = Path(path)
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
