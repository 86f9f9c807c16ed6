"""One compiled entry point over every model: ``step_lanes(model, ...)``.

Kernels that run episodes (the episode engine, Q-learning) are module-level
functions taking the model's number, so numba's disk cache serves them in every process.
A new model adds one branch here (and its name to ``sim_nodes.models.MODELS``).
"""
from sim_nodes.jit import kernel
from sim_nodes.models import MODELS, acrobot, mountain_car, pdip

ACROBOT, PDIP, MOUNTAIN_CAR = (MODELS.index(m) for m in ('acrobot', 'pdip', 'mountain_car'))


@kernel
def step_lanes(model, S, action, p, n, reward):
    """``mdp_step_lanes`` of model number ``model`` (its index in MODELS)."""
    if model == ACROBOT:
        acrobot.mdp_step_lanes(S, action, p, n, reward)
    elif model == PDIP:
        pdip.mdp_step_lanes(S, action, p, n, reward)
    elif model == MOUNTAIN_CAR:
        mountain_car.mdp_step_lanes(S, action, p, n, reward)
    else:
        reward[:n] = float('nan')
