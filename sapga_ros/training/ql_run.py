"""The Q-learning baseline's training run: the one training loop
(``sapga_ros.training.loop.train``) with ``method`` 'ql'."""
from __future__ import annotations

from dataclasses import replace
from typing import Callable

from sapga_ros.training.loop import Progress, TrainConfig, TrainResult, train


def train_ql(config: TrainConfig, progress: Progress | None = None,
             should_stop: Callable[[], bool] | None = None) -> TrainResult:
    """Run the Q-learning baseline as configured; it ends early, keeping what it learnt,
    once ``should_stop()`` is true (checked after every chunk of ``config.ql.chunk_steps``)."""
    return train(replace(config, method='ql'), progress=progress, should_stop=should_stop)
