"""What ``sapga experiment`` checks before any run starts: the whole experiment set (rows
and limit searches), the options (bounded ``--seeds`` and ``--scale``, a well-formed Ray
address) and the folders of the output directory (never a link out of it)."""
from __future__ import annotations

import math
from pathlib import Path

from sapga_ros.errors import ConfigError
from sapga_ros.training.experiment_set import (MAX_SCALE, MAX_SEEDS, Experiment, LimitSearch,
                                               load_experiments, load_limits)

Request = tuple[list[Experiment], int, list[LimitSearch]]


def check_request(name: str, only: list[int] | None, seeds: int | None, scale: float,
                  backend: str, address: str | None) -> Request:
    """The experiments, seed count and limit searches of the request, every part of the
    set and of the options checked before anything runs."""
    if backend not in ('local', 'ray'):
        raise ConfigError(f'unknown backend {str(backend)[:40]!r} (known: local, ray)')
    exps, default_seeds = load_experiments(name)
    searches = load_limits(name)
    if only:
        unknown = set(only) - {e.id for e in exps}
        if unknown:
            raise ConfigError(f'no experiment {sorted(unknown)[:10]} in {name}')
        exps = [e for e in exps if e.id in only]
    if seeds is not None and (isinstance(seeds, bool) or not isinstance(seeds, int)
                              or not 1 <= seeds <= MAX_SEEDS):
        raise ConfigError(f'--seeds must be a whole number in [1, {MAX_SEEDS}], '
                          f'got {str(seeds)[:40]}')
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or \
            not (math.isfinite(scale) and 0 < scale <= MAX_SCALE):
        raise ConfigError(f'--scale must be a number in (0, {MAX_SCALE:g}], got {scale}')
    if backend == 'ray' and address:
        from sapga_ros.training.ray_address import parse_address
        parse_address(address)
    return exps, default_seeds if seeds is None else seeds, searches


def subdir(out: Path, name: str) -> Path:
    """``out/name``, made if absent; a symbolic link or a file there is refused (every
    output stays inside ``out``)."""
    path = out / name
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise ConfigError(f'{path}: not a directory of this experiment (a link or a file); '
                          'remove it or use another --out')
    path.mkdir(parents=True, exist_ok=True)
    return path
