"""The controller row of a policy: the packed float64 vector the compiled controller
(``sapga_ros.evaluation.control``) reads, and the policy kinds (``classical``) write.

Layout: [mode, c, swing-up kind, delay d (MDP steps of actuation delay the controller is
designed for), NG swing-up constants, K (D), P (D*D)].  Modes: ``NONE`` (exemplars only),
``CATCH`` (the hybrid: the LQR inside x'Px <= c, the exemplars outside), ``CLASSICAL``
(the LQR inside, the energy swing-up outside), ``AHEAD`` (exemplars only, selecting on the
state predicted ``delay`` MDP steps ahead; no LQR).  Swing-up kinds: ``SWING_ACROBOT``
(Spong-style energy pumping), ``SWING_CART`` (Astrom-Furuta on the summed pole energy, plus
cart centring).
"""
NONE, CATCH, CLASSICAL, AHEAD = 0, 1, 2, 3
NO_SWING, SWING_ACROBOT, SWING_CART = 0, 1, 2
MODE, C, SWING, DELAY, GAINS = 0, 1, 2, 3, 4
NG = 12                       # swing-up constants
HEAD = GAINS + NG             # K starts here
MAX_DELAY = 16                # MDP steps of actuation delay a controller may compensate
