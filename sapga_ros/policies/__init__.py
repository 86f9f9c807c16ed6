"""Every kind of policy with its file format: exemplar policies (``exemplar``, their styles in
``styles``), the Q-table of the Q-learning baseline (``qtable``), the classical controller
and the LQR catch (``classical``, ``lqr``, the packed ``controller_row``), the strict JSON
they share (``jsonfile``, ``jsonstream``) and the reader that tells the kinds apart
(``kinds``)."""
