"""Compiled entry points over every model: ``step_lanes(model, ...)`` (one parameter
vector for every lane) and ``step_lanes_each(model, ...)`` (row k of a parameter array for
lane k: mismatched plants, each episode its own).

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

import numpy as np

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


def lane_by_lane(step_model: Callable) -> Callable:
    """An ``mdp_step_lanes_each`` made of ``step_model`` (an ``mdp_step_lanes``): each lane
    stepped alone with its row of P (for a model without its own; the reference the
    vectorised ones are tested against)."""
    @kernel(cache=False)
    def each(S, action, P, n, reward):
        s1 = np.empty((S.shape[0], 1))
        a1 = np.empty(1)
        r1 = np.empty(1)
        for k in range(n):
            s1[:, 0] = S[:, k]
            a1[0] = action[k]
            step_model(s1, a1, P[k], 1, r1)
            S[:, k] = s1[:, 0]
            reward[k] = r1[0]
    return each


def _dispatch(models: tuple[str, ...], each: bool = False) -> Callable:
    """The chain of branches over ``models`` (numbered by their index), first one first;
    ``each``: of their ``mdp_step_lanes_each``."""
    chain = _unknown
    for number in reversed(range(len(models))):
        module = model_module(models[number])
        step = module.mdp_step_lanes
        if each:
            step = getattr(module, 'mdp_step_lanes_each', None) or lane_by_lane(step)
        chain = _branch(number, step, chain)
    return chain


_STEP = _dispatch(MODELS)
_STEP_EACH = _dispatch(MODELS, each=True)


@kernel
def step_lanes(model, S, action, p, n, reward):
    """``mdp_step_lanes`` of model number ``model`` (its index in MODELS)."""
    _STEP(model, S, action, p, n, reward)


@kernel
def step_lanes_each(model, S, action, P, n, reward):
    """``mdp_step_lanes_each`` of model number ``model``: lane k with parameters P[k]."""
    _STEP_EACH(model, S, action, P, n, reward)
