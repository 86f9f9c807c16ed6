"""Registry of dynamics kernels: ``model`` in a problem YAML names a module here.

A model module provides, all compiled with numba and free of Python objects:

* ``PARAMS``: the names of its ``physics`` parameters, in kernel order;
* ``pack_params(problem) -> float64[:]``: ``[dt, substeps, *physics]``;
* ``mdp_step(s, action, p) -> reward``: advance the state ``s`` in place by one MDP step
  (``substeps`` integration substeps holding ``action``) and return that step's reward.

Goal area and ``delta(s)`` are data (``goal`` in the YAML), shared by every model
(``sim_nodes.goal``).  A new problem is one YAML file plus one module here: MODELS
(``registry.py``), the compiled dispatch (``dispatch.py``) and the simulator executables
find every module that defines ``mdp_step_lanes``.
"""
from __future__ import annotations

import importlib
from types import ModuleType

from sim_nodes.errors import ConfigError
from sim_nodes.models.registry import model_names

MODELS = model_names()


def model_id(name: str) -> int:
    """The number the compiled kernels know model ``name`` by."""
    if name not in MODELS:
        raise ConfigError(f'unknown model {name!r} (known: {", ".join(MODELS)})')
    return MODELS.index(name)


def model_module(name: str) -> ModuleType:
    """The kernel module of model ``name``."""
    if name not in MODELS:
        raise ConfigError(f'unknown model {name!r} (known: {", ".join(MODELS)})')
    return importlib.import_module(f'sim_nodes.models.{name}')


def pack_physics(problem, names: tuple[str, ...]):
    """``[dt, substeps, *physics[names]]`` as float64, checking the names are all present."""
    import numpy as np
    missing = [n for n in names if n not in problem.physics]
    extra = [n for n in problem.physics if n not in names]
    if missing or extra:
        raise ConfigError(f'{problem.source}: physics: missing {missing}, unknown {extra} '
                          f'(model {problem.model} takes {", ".join(names)})')
    values = [problem.dt, float(problem.substeps)] + [problem.physics[n] for n in names]
    return np.array(values, dtype=np.float64)
