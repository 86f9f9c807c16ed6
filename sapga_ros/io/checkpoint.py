"""Checkpoints of a training run: one NPZ file, written atomically, read without pickle.

Arrays hold the population (exemplars, values, referral marks) and the best policy; a
``meta`` entry holds a JSON document (run settings, counters, the generator's bit-generator
state, the log so far).  Resuming restores all of it, so a resumed run continues to the
identical result.
"""
from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from sapga_ros.errors import CheckpointError
from sapga_ros.io.atomic import write_atomic

FORMAT = 'sapga-checkpoint/1'
FILENAME = 'checkpoint.npz'


def save_checkpoint(directory: str | os.PathLike, meta: dict[str, Any],
                    arrays: dict[str, np.ndarray]) -> Path:
    """Write ``directory/checkpoint.npz`` atomically (temporary file + rename)."""
    doc = json.dumps({'format': FORMAT, **meta}, allow_nan=True).encode()
    return write_atomic(Path(directory) / FILENAME, lambda f: np.savez(
        f, meta=np.frombuffer(doc, dtype=np.uint8), **arrays))


def load_checkpoint(directory: str | os.PathLike) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read ``directory/checkpoint.npz``: (meta, arrays); CheckpointError if unusable."""
    path = Path(directory) / FILENAME
    if not path.is_file():
        raise CheckpointError(f'{path}: no checkpoint to resume from')
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise CheckpointError(f'{path}: unreadable checkpoint ({exc})') from exc
    if 'meta' not in arrays:
        raise CheckpointError(f'{path}: missing meta record')
    try:
        meta = json.loads(arrays.pop('meta').tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CheckpointError(f'{path}: malformed meta record ({exc})') from exc
    if not isinstance(meta, dict) or meta.get('format') != FORMAT:
        raise CheckpointError(f'{path}: not a {FORMAT} file')
    return meta, arrays
