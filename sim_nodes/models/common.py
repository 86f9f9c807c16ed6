"""Helpers shared by the dynamics kernels."""
import math

import numpy as np
from sim_nodes.jit import kernel

TWO_PI = 2.0 * math.pi


@kernel
def wrap_angle(theta: float) -> float:
    """theta wrapped to [0, 2pi)."""
    w = theta - TWO_PI * np.floor(theta / TWO_PI)  # np.floor: a float, vectorisable
    if (w >= TWO_PI) | (w < 0.0):  # rounding of a tiny negative theta
        w = 0.0
    return w


@kernel
def clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else (hi if x > hi else x)
