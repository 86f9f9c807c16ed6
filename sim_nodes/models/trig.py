"""sin and cos in plain floating-point arithmetic (fdlibm's kernels), for the dynamics.

Why not libm: these compile to the same instructions in a scalar call (the ROS simulator
node) and in a batch kernel, vectorise freely, and give bit-identical results on every
machine whatever its libm.  Accuracy: within 2 ulp of libm for the arguments a pendulum
sees (|x| up to 1e5 rad), checked against numpy in the tests.

Argument reduction (Cody-Waite in three parts, as fdlibm's medium case): n = round(x 2/pi),
r = ((x - n pio2_1) - n pio2_2) - n pio2_2t, |r| <= pi/4; then fdlibm's polynomial kernels.
"""
import numpy as np
from sim_nodes.jit import kernel

INV_PIO2 = 6.36619772367581382433e-01   # 2/pi
PIO2_1 = 1.57079632673412561417e+00     # first 33 bits of pi/2 (n * PIO2_1 is exact)
PIO2_2 = 6.07710050630396597660e-11     # next 33 bits
PIO2_2T = 2.02226624879595063154e-21    # pi/2 - PIO2_1 - PIO2_2
S1 = -1.66666666666666324348e-01        # sin kernel: x + x^3 (S1 + z (S2 + ...)), z = x^2
S2 = 8.33333333332248946124e-03
S3 = -1.98412698298579493134e-04
S4 = 2.75573137070700676789e-06
S5 = -2.50507602534068634195e-08
S6 = 1.58969099521155010221e-10
C1 = 4.16666666666666019037e-02         # cos kernel: 1 - z/2 + z^2 (C1 + z (C2 + ...))
C2 = -1.38888888888741095749e-03
C3 = 2.48015872894767294178e-05
C4 = -2.75573143513906633035e-07
C5 = 2.08757232129817482790e-09
C6 = -1.13596475577881948265e-11


@kernel(inline='always')
def sincos(x):
    """(sin x, cos x)."""
    n = np.floor(x * INV_PIO2 + 0.5)             # float: keeps the loop vectorisable
    r = ((x - n * PIO2_1) - n * PIO2_2) - n * PIO2_2T  # |r| <= pi/4
    z = r * r
    v = z * r
    s = r + v * (S1 + z * (S2 + z * (S3 + z * (S4 + z * (S5 + z * S6)))))
    hz = 0.5 * z
    w = 1.0 - hz
    c = w + (((1.0 - w) - hz) + z * z * (C1 + z * (C2 + z * (C3 + z * (C4 + z * (C5 + z * C6))))))
    # quadrant q = n mod 4 selects and signs the results; float arithmetic only (no
    # branches, which a scalar call would mispredict) so that loops over many states
    # vectorise; x * 1.0 + y * 0.0 == x exactly (and NaN when y is infinite, as it must).
    # sin < 0 in quadrants 2 and 3, cos < 0 in quadrants 1 and 2 (of r): the signs from
    # two floors, each an exact +-1.0.
    q = n - 4.0 * np.floor(0.25 * n)
    half = np.floor(0.5 * q)                     # 1.0 in quadrants 2 and 3
    odd = q - 2.0 * half                         # 1.0 in quadrants 1 and 3
    even = 1.0 - odd
    sign_s = 1.0 - 2.0 * half
    sign_c = sign_s * (1.0 - 2.0 * odd)
    return sign_s * (odd * c + even * s), sign_c * (odd * s + even * c)


@kernel(inline='always')
def sin(x):
    return sincos(x)[0]


@kernel(inline='always')
def cos(x):
    return sincos(x)[1]
