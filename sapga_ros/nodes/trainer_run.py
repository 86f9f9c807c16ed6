"""One run of the trainer node: the training loop in a background thread.

``TrainingRun`` trains one ``TrainConfig`` through ``training.loop.train`` (the fast batch
evaluator, never ROS topics), keeps the log rows, writes the best policy and its log to
``out`` at every save of the loop (at least every ``checkpoint_seconds``) and at the end,
and reports through ``RunStatus`` and the node's hooks.  ``stop()`` ends it after its
current round, saved.  Whatever happens, the state leaves ``training``: ``done``,
``stopped`` or ``failed`` with one line saying why.
"""
from __future__ import annotations

import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from sapga_ros.errors import SapgaError
from sapga_ros.nodes.trainer_status import RunStatus
from sapga_ros.training.loop import TrainConfig


@dataclass(frozen=True)
class RunHooks:
    """What a run tells its node: a better policy, the final one, that the status changed;
    how it logs; how often it logs progress [s]."""

    best: Callable[[Any], None]
    result: Callable[[Any], None]
    changed: Callable[[], None]
    say: Callable[[str, str], None]
    log_period: Callable[[], float]


class TrainingRun:
    """A training run in its own thread."""

    def __init__(self, config: TrainConfig, out: str, status: RunStatus,
                 hooks: RunHooks) -> None:
        self.config, self.out, self.status, self.hooks = config, out, status, hooks
        self.history: list[dict] = []
        self._stop = threading.Event()
        self._last_log = time.monotonic()
        self._thread = threading.Thread(target=self._run, name='sapga-training', daemon=True)

    def start(self) -> None:
        self._thread.start()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def stop(self, timeout: float) -> bool:
        """Ask the run to end after its round (saving) and wait; True once it has ended."""
        self._stop.set()
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def _set(self, **values: Any) -> None:
        self.status.update(**values)
        self.hooks.changed()

    def _run(self) -> None:
        out = self.out
        try:
            self._train()
        except SapgaError as exc:
            self._set(state='failed', message=f'training failed: {exc}')
        except OSError as exc:
            self._set(state='failed', message=(
                f'cannot write {exc.filename2 or exc.filename or out}: {exc.strerror or exc}; '
                'the best policy is still served on get_policy'))
        except BaseException as exc:  # noqa: BLE001 - reported; the node goes on serving
            self.hooks.say('error', traceback.format_exc())
            self._set(state='failed', message=f'training failed: {type(exc).__name__}: {exc}')
        finally:
            if self.status.snapshot()['state'] == 'training':
                self._set(state='failed', message='training failed')
        st = self.status.snapshot()
        self.hooks.say('error' if st['state'] == 'failed' else 'info', st['message'])

    def _save(self, policy: Any, history: list[dict]) -> None:
        """The best policy and the log so far to ``out`` (at each save and at the end)."""
        from sapga_ros.training.loop import write_log
        if self.out:
            policy.save(self.out)
            write_log(Path(self.out).with_suffix('.log.csv'), history)

    def _train(self) -> None:
        from sapga_ros.training.loop import train
        config, out = self.config, self.out
        # stop only after a round: a run always has a best policy to save
        result = train(config, (), self._on_progress, self.hooks.best,
                       lambda: self._stop.is_set() and bool(self.history), self._save)
        self.hooks.result(result.policy)
        self._save(result.policy, result.history)
        meta = result.policy.meta
        state = 'stopped' if result.stop.get('should_stop') else 'done'
        saved = [f'policy {out}' if out else 'no out file (the policy is served on '
                                             'get_policy)']
        if config.checkpoint:
            saved.append(f'checkpoint {config.checkpoint}')
        self._set(state=state, message=(
            f'{state} after {meta["steps"]} steps: best value {meta["value"]:.3f}, policy '
            f'delta* {meta["delta_star"]:.4f}, run delta* {meta["run_delta_star"]:.4f}; saved '
            + ', '.join(saved)))

    def _on_progress(self, row: dict) -> None:
        self.history.append(row)
        self.status.update(steps=row['steps'], best_value=row['best_value'],
                           delta_star=row['delta_star'], steps_per_s=row['steps_per_s'],
                           generation=row.get('generation', 0),
                           episodes=row.get('episodes', 0))
        now = time.monotonic()
        if now - self._last_log >= self.hooks.log_period():
            self._last_log = now
            st = self.status.snapshot()
            self.hooks.say('info', f'steps {st["steps"]:,d} / {st["budget"]:,d}  best '
                                   f'{st["best_value"]:.3f}  delta* {st["delta_star"]:.4f}  '
                                   f'{st["steps_per_s"] / 1e6:.2f} M steps/s')
