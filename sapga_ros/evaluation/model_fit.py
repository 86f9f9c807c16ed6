"""The plant's masses and lengths, fitted to the transitions a controller sees.

A planner that plans on the nominal model plans for a plant that is not there: five per cent
of model error is enough to turn an entry the model promised into a near miss.  ``ModelFit``
keeps the last ``WINDOW`` transitions (state seen, command applied, next state seen) and
estimates a factor on every mass and length of the model's physics (the entries a bench
measures imperfectly, the ``masses`` and ``lengths`` groups of the disturbance profiles):
the maximum a posteriori estimate under a log-normal prior of relative spread ``prior``
around the nominal values and residuals of size ``NOISE`` per coordinate, found by
Gauss-Newton steps (``STEPS`` at each new transition, warm-started from the last estimate),
the Jacobian by forward differences of the model kernel stepping every transition with each
nudged parameter vector side by side.  The residuals' loss is Huber's: quadratic up to
``HUBER`` x ``NOISE``, linear beyond (iteratively reweighted), so that a transition the
model cannot explain -- a push, a state lost on the way so that two steps look like one --
pulls the estimate no more than a few ordinary ones; a transition with a value that is not
finite is not kept.  Directions the transitions do not determine stay at the prior's
centre.  The estimate is a pure function of the transitions, so a controller using it is
still a function of the states it has seen.
"""
from __future__ import annotations

import numpy as np

from sim_nodes.disturbance import GROUPS
from sim_nodes.jit import kernel
from sim_nodes.models.dispatch import step_lanes

WINDOW = 100       # transitions kept (the most recent)
MIN_SEEN = 4       # transitions before the first estimate
STEPS = 2          # Gauss-Newton steps per transition
NOISE = 0.005      # the residual a transition is expected to leave, per coordinate
HUBER = 3.0        # residuals beyond HUBER x NOISE weigh linearly, not quadratically
NUDGE = 1e-4       # forward-difference step of a log factor
LIMIT = 3.0        # an estimate stays within LIMIT x prior of the nominal value (log scale)


@kernel(nogil=True)
def transition_residuals(model, X, A, Y, n, P, is_angle, S, a, r, R):
    """R[j, i * n + t]: coordinate i of Y[:, t] minus the model with parameters P[j] stepped
    one MDP step from X[:, t] with command A[t] (angles the short way round), t < n."""
    dim = X.shape[0]
    for j in range(P.shape[0]):
        for t in range(n):
            a[t] = A[t]
            for i in range(dim):
                S[i, t] = X[i, t]
        step_lanes(model, S, a, P[j], n, r)
        for i in range(dim):
            for t in range(n):
                d = Y[i, t] - S[i, t]
                if is_angle[i]:
                    d = (d + np.pi) % (2.0 * np.pi) - np.pi
                R[j, i * n + t] = d


def fitted_entries(problem) -> np.ndarray:
    """Indices into the packed parameter vector ([dt, substeps, *PARAMS]) of the model's
    masses and lengths."""
    from sim_nodes.models import model_module
    names = model_module(problem.model).PARAMS
    return np.array([2 + i for i, n in enumerate(names)
                     if any(g.match(n) for g in GROUPS.values())], dtype=np.int64)


class ModelFit:
    """The fitted parameter vector of ``problem``'s model (see the module docstring):
    ``reset()`` at an episode's start, ``add(x, a, y)`` for each transition, ``params``."""

    def __init__(self, problem, model: int, prior: float) -> None:
        self.problem, self.model, self.prior = problem, model, prior
        self.nominal = problem.params()
        self.entries = fitted_entries(problem)
        dim, k = problem.dim, len(self.entries)
        self.X, self.Y = np.empty((dim, WINDOW)), np.empty((dim, WINDOW))
        self.A = np.empty(WINDOW)
        self.S, self.a, self.r = np.empty((dim, WINDOW)), np.empty(WINDOW), np.empty(WINDOW)
        self.R = np.empty((k + 1, dim * WINDOW))
        self.P = np.empty((k + 1, len(self.nominal)))
        self.reset()

    def reset(self) -> None:
        self.theta = np.zeros(len(self.entries))      # log factors
        self.count = 0
        self.params = self.nominal.copy()

    def factors(self) -> np.ndarray:
        """The fitted factor of each entry (``entries``) on its nominal value."""
        return np.exp(self.theta)

    def add(self, x: np.ndarray, a: float, y: np.ndarray) -> None:
        """The transition from the state seen ``x`` under the applied command ``a`` to the
        state seen ``y``; the estimate (``params``) updated."""
        if not (np.all(np.isfinite(x)) and np.isfinite(a) and np.all(np.isfinite(y))):
            return
        slot = self.count % WINDOW
        self.X[:, slot], self.A[slot], self.Y[:, slot] = x, a, y
        self.count += 1
        if self.count >= MIN_SEEN and len(self.entries):
            for _ in range(STEPS):
                self._step(min(self.count, WINDOW))

    def _vector(self, theta: np.ndarray) -> np.ndarray:
        p = self.nominal.copy()
        p[self.entries] *= np.exp(theta)
        return p

    def _step(self, n: int) -> None:
        k = len(self.entries)
        self.P[0] = self._vector(self.theta)
        for i in range(k):
            self.P[1 + i] = self.P[0]
            self.P[1 + i, self.entries[i]] *= np.exp(NUDGE)
        transition_residuals(self.model, self.X, self.A, self.Y, n, self.P,
                             self.problem.is_angle, self.S, self.a, self.r, self.R)
        r0 = self.R[0, :self.problem.dim * n]
        J = (self.R[1:, :self.problem.dim * n] - r0) / NUDGE
        w = np.minimum(1.0, HUBER * NOISE / np.maximum(np.abs(r0), 1e-300))  # Huber's
        H = (J * w) @ J.T / NOISE ** 2 + np.eye(k) / self.prior ** 2
        g = (J * w) @ r0 / NOISE ** 2 + self.theta / self.prior ** 2
        theta = self.theta - np.linalg.solve(H, g)
        if np.all(np.isfinite(theta)):
            self.theta = np.clip(theta, -LIMIT * self.prior, LIMIT * self.prior)
            self.params = self._vector(self.theta)
