"""One compiled entry point over every model: ``step_lanes(model, ...)``.

Kernels that run episodes (the episode engine, Q-learning) are module-level
functions taking the model's number, so numba's disk cache serves them in every process.
The branches are built here from ``MODELS``, one per model module: a new model needs
nothing in this file.  numba calls a function it knows at compile time, so each branch is a
small compiled function holding its model's number and kernel and the branch to try next;
they are compiled into ``step_lanes`` (and cached with it and its callers).  The cache
folder is keyed by every kernel file (``sim_nodes.jit``), so a model added, removed or
renamed is never served stale.
"""
from typing import Callable

from sim_nodes.jit import kernel
from sim_nodes.models import MODELS, model_module


@kernel(cache=False)
def _unknown(model, S, action, p, n, reward):
    """No model has this number: NaN rewards."""
    reward[:n] = float('nan')


def _branch(number: int, step_model: Callable, otherwise: Callable) -> Callable:
    """``step_model`` (an ``mdp_step_lanes``) for model ``number``, else ``otherwise``."""
    @kernel(cache=False)
    def branch(model, S, action, p, n, reward):
        if model == number:
            step_model(S, action, p, n, reward)
        else:
            otherwise(model, S, action, p, n, reward)
    return branch


def _dispatch(models: tuple[str, ...]) -> Callable:
    """The chain of branches over ``models`` (numbered by their index), first one first."""
    chain = _unknown
    for number in reversed(range(len(models))):
        chain = _branch(number, model_module(models[number]).mdp_step_lanes, chain)
    return chain


_STEP = _dispatch(MODELS)


@kernel
def step_lanes(model, S, action, p, n, reward):
    """``mdp_step_lanes`` of model number ``model`` (its index in MODELS)."""
    _STEP(model, S, action, p, n, reward)
