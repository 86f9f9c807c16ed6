"""Output paths checked before any work is done: a file or a directory that cannot be
written is refused with one line naming the option; no folder that does not exist is
created.
"""
from __future__ import annotations

import os
from pathlib import Path

from sapga_ros.errors import SapgaError


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


def check_output_dir(path: Path, option: str, parents: bool = False) -> None:
    """Refuse an output directory that cannot be used: one that is a file, or, if it does
    not exist yet, whose parent folder does not exist or cannot be written.  With
    ``parents`` (a command that makes the missing folders) the nearest folder that exists
    is the one that must be a writable folder."""
    if path.exists():
        if not path.is_dir():
            raise SapgaError(f'{option} {path}: exists and is not a directory')
        if not os.access(path, os.W_OK | os.X_OK):
            raise SapgaError(f'{option} {path}: not writable')
        return
    folder = path.parent
    if parents:
        while not folder.exists() and folder != folder.parent:
            folder = folder.parent
    _check_folder(path, option, folder)


def _check_folder(path: Path, option: str, folder: Path | None = None) -> None:
    """``folder`` (``path``'s, unless given) is a writable folder."""
    folder = path.parent if folder is None else folder
    if not folder.is_dir():
        what = 'is not a folder' if folder.exists() else 'does not exist'
        raise SapgaError(f'{option} {path}: {folder} {what}')
    if not os.access(folder, os.W_OK | os.X_OK):
        raise SapgaError(f'{option} {path}: folder {folder} is not writable')
