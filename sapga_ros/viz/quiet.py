"""Drawing hostile but accepted numbers without a word on stderr.

The files a figure is drawn from are checked for finiteness, not for being pleasant to
draw: finite extremes (1e308, 5e-324) make numpy overflow in matplotlib's tick and limit
arithmetic and matplotlib warn about singular or non-positive limits.  The figure is drawn
all the same; those warnings are about the picture, not the data, so the drawing functions
run under ``quiet_drawing`` and a command prints only its own lines.
"""
from __future__ import annotations

import warnings
from contextlib import contextmanager
from typing import Iterator


@contextmanager
def quiet_drawing() -> Iterator[None]:
    """Ignore RuntimeWarning and UserWarning inside (also a decorator)."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)
        warnings.simplefilter('ignore', UserWarning)
        yield
