"""A training run's checkpoints: what they record beside the optimizer's state, and how a run
resumes from one, trusting nothing in it.

Beside ``Optimizer.state_dict()`` a checkpoint (``sapga_ros.io.checkpoint``) records:

* ``run``: what a resumed run must share with it (problem, method, delta, seed, strategy
  parameters); a run of other settings is refused with one line naming the differences;
* ``settings``: every setting of the run (``sapga train --resume`` takes those not given
  on its command line from here: budget, jobs, style, ...);
* ``history``: the log rows so far.

``restore`` checks all of it before the run goes on: the history must be a list of log
rows, the counters numbers (steps and rounds whole and >= 0); anything that fails while the
optimizer is rebuilt is a ``CheckpointError`` naming the checkpoint, never a traceback.
"""
from __future__ import annotations

import math
from dataclasses import fields, is_dataclass
from typing import Any, Callable

from sapga_ros.errors import CheckpointError, ConfigError
from sapga_ros.io.checkpoint import load_checkpoint, save_checkpoint
from sapga_ros.optim.base import Optimizer, State
from sim_nodes.params import declared


def settings_of(config: Any) -> dict[str, Any]:
    """Every parameter of ``config`` and of its dataclass fields, by name."""
    out: dict[str, Any] = {}
    for p in declared(type(config)):
        out[p.name] = getattr(config, p.name)
    for f in fields(config):
        value = getattr(config, f.name)
        if is_dataclass(value):
            out.update(settings_of(value))
    return out


def flat(run: Any) -> dict[str, Any]:
    """The run settings with nested mappings (``params``) flattened: name -> value."""
    if not isinstance(run, dict):
        return {}
    out: dict[str, Any] = {}
    for key, value in run.items():
        if isinstance(value, dict):
            out.update(flat(value))
        else:
            out[str(key)] = value
    return out


def difference(saved: Any, want: dict) -> str:
    """'problem pdip, seed 3; this run: problem acrobot, seed 0': the settings that differ."""
    a, b = flat(saved), flat(want)
    keys = [k for k in dict.fromkeys([*b, *a]) if a.get(k, '?') != b.get(k, '?')]
    show = lambda d: ', '.join(f'{k} {d.get(k, "(none)")}' for k in keys)  # noqa: E731
    return f'{show(a)}; this run: {show(b)}'[:300]


def save(directory: str, run: dict, settings: dict[str, Any], opt: Optimizer,
         history: list[dict]) -> None:
    """Write the run's checkpoint into ``directory``."""
    meta, arrays = opt.state_dict()
    save_checkpoint(directory, {'run': run, 'settings': settings, **meta, 'history': history},
                    arrays)


def restore(directory: str, run: dict, rebuild: Callable[[State], Optimizer]
            ) -> tuple[Optimizer, list[dict]]:
    """The optimizer (``rebuild(state)``) and log of the checkpoint in ``directory``, if it
    is of the run ``run`` and its contents hold up."""
    meta, arrays = load_checkpoint(directory)
    if not isinstance(meta.get('run'), dict):
        raise CheckpointError(f'{directory}: the checkpoint records no run settings')
    if older_run(meta['run'], meta.get('settings'), run) != run:
        raise CheckpointError(f'{directory}: checkpoint is of {difference(meta["run"], run)}')
    try:
        history = check_history(meta.get('history', []))
        opt = rebuild((meta, arrays))
        check_counters(opt)
    except (CheckpointError, ConfigError) as exc:
        raise CheckpointError(f'{directory}: {exc}') from exc
    except MemoryError:
        raise
    except Exception as exc:  # noqa: BLE001 - no checkpoint content may crash the run
        raise CheckpointError(f'{directory}: unusable run state ({type(exc).__name__}: '
                              f'{exc})'[:300]) from exc
    return opt, history


def older_run(saved: dict, settings: Any, run: dict) -> dict:
    """``saved`` with each run setting that ``run`` names and ``saved`` lacks taken from the
    checkpoint's ``settings``: a checkpoint written before that setting was a run setting
    (the catch of a hybrid run) resumes when it recorded the same value."""
    if not isinstance(settings, dict):
        return saved
    return {**saved, **{k: settings[k] for k in run if k not in saved and k in settings}}


def check_history(history: Any) -> list[dict]:
    """The log rows of a checkpoint, if they are a list of {name: JSON scalar} rows."""
    if not isinstance(history, list):
        raise CheckpointError(f'history: expected a list of log rows, got '
                              f'{type(history).__name__}')
    for i, row in enumerate(history):
        if not isinstance(row, dict) or not all(
                isinstance(k, str) and (v is None or isinstance(v, (bool, int, float)))
                for k, v in row.items()):
            raise CheckpointError(f'history[{i}]: expected a log row (names to numbers)')
    return list(history)


def check_counters(opt: Optimizer) -> None:
    """CheckpointError unless the restored counters are numbers, steps and rounds whole."""
    for name, value in opt.counters().items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                (isinstance(value, float) and math.isnan(value)):
            raise CheckpointError(f'counter {name}: expected a number, got {value!r}'[:200])
    for name, value in (('steps', opt.steps), ('rounds', opt.iteration)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise CheckpointError(f'counter {name}: expected a whole number >= 0, got '
                                  f'{value!r}'[:200])
