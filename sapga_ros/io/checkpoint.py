"""Checkpoints of a training run: one NPZ file, written atomically, read without pickle and
without trusting its sizes.

Arrays hold the population (exemplars, values, referral marks) and the best policy; a
``meta`` entry holds a JSON document (run settings, counters, the generator's bit-generator
state, the log so far).  Resuming restores all of it, so a resumed run continues to the
identical result.

Reading is bounded (a checkpoint is input like any other): a regular file of at most
``MAX_BYTES``; at most ``MAX_MEMBERS`` members, each a plain ``<name>.npy`` of a numeric or
bool array; the members' declared uncompressed sizes are checked before a byte is inflated
(in all at most ``MAX_BYTES`` and ``MAX_RATIO`` times the file size: ``np.savez`` stores its
members, so a zip bomb is refused unopened); each array's header must describe exactly the
bytes that follow it (never an allocation its data cannot fill); the meta JSON must be
strict JSON within Python's nesting limit.  Every refusal is a one-line ``CheckpointError``.

The meta JSON is strict: an inf or NaN of the run (the best value or delta* before any
episode reached anything) is written tagged (``sapga_ros.io.jsonfile.tagged_dumps``) and
reads back as the same float; a bare ``NaN`` or ``Infinity`` is refused, naming the field.
"""
from __future__ import annotations

import io
import os
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from sapga_ros.errors import CheckpointError
from sapga_ros.io.atomic import write_atomic
from sapga_ros.io.bounded import open_regular
from sapga_ros.io.jsonfile import strict_loads, tagged_dumps

FORMAT = 'sapga-checkpoint/1'
FILENAME = 'checkpoint.npz'
MAX_BYTES = 2 * 2 ** 30         # [bytes] of the file, and of its members uncompressed
MAX_RATIO = 20                  # uncompressed bytes per stored byte, at most (1 as written)
MAX_MEMBERS = 256
_NAME = re.compile(r'[A-Za-z0-9_]{1,100}\.npy')
_KINDS = 'biuf'                 # bool, signed and unsigned integers, floats


def checkpoint_file(directory: str | os.PathLike) -> Path:
    """Where the checkpoint of ``directory`` lives."""
    return Path(directory) / FILENAME


def save_checkpoint(directory: str | os.PathLike, meta: dict[str, Any],
                    arrays: dict[str, np.ndarray]) -> Path:
    """Write ``directory/checkpoint.npz`` atomically (temporary file + rename)."""
    doc = tagged_dumps({'format': FORMAT, **meta}).encode()
    return write_atomic(checkpoint_file(directory), lambda f: np.savez(
        f, meta=np.frombuffer(doc, dtype=np.uint8), **arrays))


def load_checkpoint(directory: str | os.PathLike) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read ``directory/checkpoint.npz``: (meta, arrays); CheckpointError if unusable."""
    path = checkpoint_file(directory)
    arrays = _read(path)
    if 'meta' not in arrays:
        raise CheckpointError(f'{path}: missing meta record')
    return _meta(path, arrays.pop('meta')), arrays


def load_checkpoint_meta(directory: str | os.PathLike) -> dict[str, Any]:
    """The meta document of ``directory/checkpoint.npz`` alone (the arrays left unread)."""
    path = checkpoint_file(directory)
    arrays = _read(path, only='meta')
    if 'meta' not in arrays:
        raise CheckpointError(f'{path}: missing meta record')
    return _meta(path, arrays['meta'])


def _read(path: Path, only: str | None = None) -> dict[str, np.ndarray]:
    """The arrays of the NPZ file ``path`` (or only the one named ``only``), bounded."""
    try:
        with open_regular(path) as f:
            size = os.fstat(f.fileno()).st_size
            if size > MAX_BYTES:
                raise CheckpointError(f'{path}: larger than {MAX_BYTES} bytes')
            with zipfile.ZipFile(f) as zf:
                members = _members(path, zf.infolist(), size)
                return {key: _array(path, key, zf, info) for key, info in members.items()
                        if only is None or key == only}
    except FileNotFoundError as exc:
        raise CheckpointError(f'{path}: no checkpoint to resume from') from exc
    except CheckpointError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, NotImplementedError,
            RuntimeError) as exc:   # RuntimeError: zipfile's 'encrypted' and friends
        reason = getattr(exc, 'strerror', None) or exc
        raise CheckpointError(f'{path}: unreadable checkpoint ({reason})'[:300]) from exc


def _members(path: Path, infos: list[zipfile.ZipInfo], size: int) -> dict[str, zipfile.ZipInfo]:
    """The members by array name, once their names, count and sizes are checked."""
    if len(infos) > MAX_MEMBERS:
        raise CheckpointError(f'{path}: {len(infos)} members, at most {MAX_MEMBERS} expected')
    members: dict[str, zipfile.ZipInfo] = {}
    for info in infos:
        if not _NAME.fullmatch(info.filename) or info.filename[:-4] in members:
            raise CheckpointError(f'{path}: unexpected member {info.filename[:100]!r}')
        if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            raise CheckpointError(f'{path}: member {info.filename} compressed with method '
                                  f'{info.compress_type}')
        members[info.filename[:-4]] = info
    total = sum(info.file_size for info in infos)
    limit = min(MAX_BYTES, MAX_RATIO * size + 2 ** 20)
    if total > limit:                              # a zip bomb: refused before inflating
        raise CheckpointError(f'{path}: its members claim {total} bytes uncompressed, more '
                              f'than {limit} for a file of {size} bytes')
    return members


def _array(path: Path, key: str, zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> np.ndarray:
    """One ``.npy`` member as an array whose header matches its data exactly."""
    data = bytearray(info.file_size)
    with zf.open(info) as member:               # inflates at most file_size bytes
        view, got = memoryview(data), 0
        while got < len(data) and (n := member.readinto(view[got:])):
            got += n
        if got != len(data) or member.read(1):
            raise CheckpointError(f'{path}: member {info.filename} is not of its stated size')
    f = io.BytesIO(data)
    version = np.lib.format.read_magic(f)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
    elif version == (2, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
    else:
        raise CheckpointError(f'{path}: {key}: unsupported .npy version {version}')
    if dtype.kind not in _KINDS or dtype.fields is not None or dtype.subdtype is not None:
        raise CheckpointError(f'{path}: {key}: arrays of {dtype} are not accepted')
    count = 1
    for n in shape:
        count *= n
    if count * dtype.itemsize != len(data) - f.tell():
        raise CheckpointError(f'{path}: {key}: header {shape} {dtype} does not match its '
                              f'{len(data) - f.tell()} bytes')
    flat = np.frombuffer(data, dtype=dtype, count=count, offset=f.tell())
    return flat.reshape(shape, order='F' if fortran else 'C')


def _meta(path: Path, raw: np.ndarray) -> dict[str, Any]:
    """The JSON document of the meta record, checked for its format."""
    if raw.dtype != np.uint8 or raw.ndim != 1:
        raise CheckpointError(f'{path}: meta record of the wrong form ({raw.dtype}, '
                              f'{raw.ndim} dimensions)')
    meta = strict_loads(raw.tobytes(), f'{path}: meta record', CheckpointError, tagged=True,
                        legacy=True)   # checkpoints of earlier versions: bare Infinity
    if not isinstance(meta, dict) or meta.get('format') != FORMAT:
        raise CheckpointError(f'{path}: not a {FORMAT} file')
    return meta
