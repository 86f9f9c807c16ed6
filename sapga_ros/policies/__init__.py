"""Every kind of policy with its file format: exemplar policies (``exemplar``, their styles in
``styles``), the Q-table of the Q-learning baseline (``qtable``), the strict JSON they share
(``jsonfile``) and the reader that tells the kinds apart (``kinds``)."""
