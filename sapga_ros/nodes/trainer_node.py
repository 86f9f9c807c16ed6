"""Trainer node: SAP-GA (or the Q-learning baseline) offline, served over ROS 2 (SPEC 4).

Training runs in a background thread through the one training loop (``training.loop.train``,
with the fast batch evaluator), never over ROS topics; the node reports progress on
``/diagnostics``, writes checkpoints and the best policy file, and serves the best policy so
far on ``get_policy``.

Parameters (msg_configs/params/trainer_node.yaml; docs/ros_interface.md has the table):
generated from the config dataclasses by ``sapga_ros.nodes.trainer_params`` -- the run's
``method``, ``steps``, ``seed``, ``jobs``, ``checkpoint_every``, ``resume``, SAP-GA's
``n_pop``, ``n_child``, ``l_min``, ``l_max``, ``style``, Q-learning's ``chunk_steps``, the
node's ``out``, ``train_on_start``, ``policy_file``, ``diagnostics_period``, ``log_period``
-- plus ``problem`` (read-only), ``delta`` and ``checkpoint``.  A change applies to the next
run.

Services (std_srvs/Trigger):

* ``get_policy``: ``message`` = the JSON document (SPEC 3.3) of the most recent of: the
  ``policy_file``, the best policy of the current or last SAP-GA run.  ``success`` false with
  the reason when there is none, and once a Q-learning run has started (a Q-table is no
  exemplar policy: the policy node cannot run it; ``sapga eval`` runs its ``out`` file).
* ``train``: starts a run with the current parameters; refused while one is running.

``/diagnostics`` (diagnostic_msgs/DiagnosticArray, one status named ``<node>: training``):
key values ``state`` (idle | training | done | failed), ``steps``, ``budget``,
``best_value``, ``delta_star``, ``delta``, ``achieved``, ``steps_per_s``, ``generation``
(SAP-GA), ``episodes`` (QL), ``method``, ``seed``, ``served`` (source of the served policy),
``out``; published every ``diagnostics_period`` and at once when the state changes.

Shutdown (Ctrl-C, SIGTERM) stops a run after its current round (``should_stop``: a SAP-GA
generation, a Q-learning chunk of ``chunk_steps``) and still writes the best policy so far
and the checkpoint.
"""
from __future__ import annotations

import math
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from sapga_ros.errors import ConfigError, SapgaError
from sim_nodes.ros.common import run_node, steady_clock
from sapga_ros.exemplars.policy import ExemplarPolicy, load_policy
from sapga_ros.nodes.trainer_params import PROBLEM, check_setting, parameters, train_config
from sapga_ros.training.loop import TrainConfig
from sim_nodes.problem import Problem, load_problem

STATES = ('idle', 'training', 'done', 'failed')
SAVE_PERIOD_S = 5.0     # [s] at most this often the improving best policy is written in a run
JOIN_TIMEOUT_S = 120.0  # [s] shutdown waits this long for the run to stop and save
QL_NOT_SERVABLE = ('method ql learns a Q-table (sapga-qtable/1), not an exemplar policy: the '
                   'policy node cannot run it (evaluate the out file with `sapga eval`; '
                   'train with method sapga to deploy)')


@dataclass(frozen=True)
class Served:
    """What ``get_policy`` answers: a policy and where it came from, or why there is none."""

    policy: ExemplarPolicy | None
    source: str
    reason: str = ''


class TrainerNode(Node):
    """Trains in a background thread; reports, saves and serves the best policy."""

    def __init__(self, node_name: str = 'trainer_node', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        name = self.declare_parameter('problem', PROBLEM[0], ParameterDescriptor(
            description=PROBLEM[1], read_only=True)).value
        self.problem: Problem = load_problem(name)
        table = parameters()
        try:
            for key, (default, descriptor) in table.items():
                self.declare_parameter(key, default, descriptor)
        except ParameterException as exc:      # a value outside the descriptor's range
            raise ConfigError(f'{self.get_name()}: parameter {exc}') from exc
        for key in table:
            reason = check_setting(key, self.get_parameter(key).value)
            if reason:
                raise ConfigError(f'{self.get_name()}: parameter {reason}')

        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closing = False
        self._served = Served(None, '', 'no policy yet: no training run has found one (call '
                                        'train, or set train_on_start or policy_file)')
        self._status: dict[str, Any] = {'state': 'idle', 'steps': 0, 'budget': 0,
                                        'best_value': -math.inf, 'delta_star': math.inf,
                                        'delta': self._delta(), 'steps_per_s': 0.0,
                                        'generation': 0, 'episodes': 0, 'message': 'idle',
                                        'method': self.get_parameter('method').value,
                                        'seed': self.get_parameter('seed').value}
        self._history: list[dict] = []
        self._last_log = 0.0
        self._last_save = 0.0
        self._pending_best: ExemplarPolicy | None = None
        self._out = ''                  # the policy file of the current or last run
        policy_file = self.get_parameter('policy_file').value
        if policy_file:
            try:
                self._serve_file(policy_file)
            except SapgaError as exc:        # keep running, serving nothing, saying why
                self.get_logger().error(f'policy_file not served: {exc}')
                self._served = Served(None, '', f'no policy yet: policy_file not served '
                                                f'({exc})')

        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._get_srv = self.create_service(Trigger, 'get_policy', self._on_get_policy)
        self._train_srv = self.create_service(Trigger, 'train', self._on_train)
        # the training thread wakes the executor to publish a state change at once
        self._wake = self.create_guard_condition(self._publish_diagnostics)
        self._diag_timer = self.create_timer(self.get_parameter('diagnostics_period').value,
                                             self._publish_diagnostics, clock=steady_clock())
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.get_logger().info(f'{self.problem.name} trainer: get_policy and train ready')
        if self.get_parameter('train_on_start').value:
            ok, message = self.start_training()
            if not ok:
                raise ConfigError(f'{self.get_name()}: cannot train: {message}')

    # configuration --------------------------------------------------------------------------

    def _delta(self) -> float:
        value = float(self.get_parameter('delta').value)
        return self.problem.default_delta if math.isnan(value) or value < 0 else value

    def train_config(self) -> TrainConfig:
        """The run the current parameters describe (``SapgaError`` if inconsistent)."""
        get = lambda key: self.get_parameter(key).value  # noqa: E731
        if get('resume') and not get('checkpoint'):
            raise ConfigError('resume needs a checkpoint directory (parameter checkpoint)')
        return train_config(get, self.problem.name, self._delta())

    def _serve_file(self, path: str) -> None:
        policy = load_policy(path, self.problem)   # PolicyFileError names what is wrong
        self._served = Served(policy, f'file {path}')
        self.get_logger().info(f'serving {path} ({len(policy)} exemplars) until training '
                               'finds a best policy')

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        for param in params:
            reason = check_setting(param.name, param.value)
            if reason is None and param.name == 'policy_file' and param.value:
                try:
                    load_policy(param.value, self.problem)
                except SapgaError as exc:
                    reason = f'policy_file: {exc}'
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        for param in params:
            if param.name == 'policy_file' and param.value:
                try:
                    self._serve_file(param.value)
                except SapgaError as exc:   # changed on disk since validation
                    self.get_logger().error(f'policy_file not served: {exc}')
            elif param.name == 'diagnostics_period':
                self.destroy_timer(self._diag_timer)
                self._diag_timer = self.create_timer(param.value, self._publish_diagnostics,
                                                     clock=steady_clock())

    # services -------------------------------------------------------------------------------

    def _on_get_policy(self, request: Trigger.Request, response: Trigger.Response
                       ) -> Trigger.Response:
        served = self._served   # one read: the training thread may replace it
        if served.policy is None:
            response.success, response.message = False, served.reason
        else:
            response.success, response.message = True, served.policy.to_json()
        return response

    def _on_train(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        response.success, response.message = self.start_training()
        return response

    @property
    def training(self) -> bool:
        """A run is in progress."""
        return self._thread is not None and self._thread.is_alive()

    def start_training(self) -> tuple[bool, str]:
        """Start a run with the current parameters; (started, message)."""
        if self.training:
            st = self.status()
            return False, (f'already training ({st["method"]}, {st["steps"]} of '
                           f'{st["budget"]} steps); wait for state done')
        if self._closing:
            return False, 'shutting down'
        try:
            config = self.train_config()
        except (SapgaError, ValueError) as exc:
            return False, str(exc)
        self._stop.clear()
        self._history = []
        self._last_log = self._last_save = time.monotonic()
        self._pending_best = None
        out = self._out = self.get_parameter('out').value
        if config.method == 'ql':
            self._served = Served(None, 'ql run', QL_NOT_SERVABLE)
        self._set_status(state='training', steps=0, budget=config.steps,
                         best_value=-math.inf, delta_star=math.inf, delta=config.delta,
                         steps_per_s=0.0, generation=0, episodes=0, method=config.method,
                         seed=config.seed, message='training')
        self._thread = threading.Thread(target=self._run, args=(config, out),
                                        name='sapga-training', daemon=True)
        self._thread.start()
        text = (f'training started: {config.problem} {config.method}, delta {config.delta}, '
                f'{config.steps} steps, seed {config.seed}'
                + (' (resumed)' if config.resume else ''))
        self.get_logger().info(text)
        return True, text

    # the run (training thread) --------------------------------------------------------------

    def _run(self, config: TrainConfig, out: str) -> None:
        from sapga_ros.training.loop import train, write_log
        try:
            # stop only after a round: a run always has a best policy to save
            result = train(config, (), self._on_progress, self._on_best,
                           lambda: self._stop.is_set() and bool(self._history))
            if config.method == 'sapga':
                self._served = Served(result.policy, 'training')
            if out:
                result.policy.save(out)
                write_log(Path(out).with_suffix('.log.csv'), result.history)
            meta = result.policy.meta
            stopped = ' (stopped early)' if self._stop.is_set() else ''
            self._set_status(state='done', message=(
                f'done{stopped}: best value {meta["value"]:.3f}, policy delta* '
                f'{meta["delta_star"]:.4f}, run delta* {meta["run_delta_star"]:.4f}, '
                f'{meta["steps"]} steps' + (f'; policy: {out}' if out else '')))
        except SapgaError as exc:
            self._set_status(state='failed', message=f'training failed: {exc}')
        except OSError as exc:
            self._set_status(state='failed', message=(
                f'cannot write {exc.filename or out}: {exc.strerror}; the best policy is '
                'still served on get_policy'))
        except Exception as exc:  # noqa: BLE001 - reported on /diagnostics, node keeps serving
            self._say('error', traceback.format_exc())
            self._set_status(state='failed',
                             message=f'training failed: {type(exc).__name__}: {exc}')
        st = self.status()
        self._say('error' if st['state'] == 'failed' else 'info', st['message'])

    def _on_best(self, policy: ExemplarPolicy) -> None:
        self._served = Served(policy, 'training')
        self._pending_best = policy

    def _on_progress(self, row: dict) -> None:
        self._history.append(row)
        self._set_status(steps=row['steps'], best_value=row['best_value'],
                         delta_star=row['delta_star'], steps_per_s=row['steps_per_s'],
                         generation=row.get('generation', 0), episodes=row.get('episodes', 0),
                         wake=False)
        now = time.monotonic()
        if self._pending_best is not None and self._out and not self._closing and \
                now - self._last_save >= SAVE_PERIOD_S:
            try:
                self._pending_best.save(self._out)
            except (OSError, SapgaError) as exc:    # the run goes on; the end retries
                self._say('warning', f'cannot write {self._out} yet: {exc}')
            self._pending_best = None
            self._last_save = now
        if now - self._last_log >= self.get_parameter('log_period').value:
            self._last_log = now
            st = self.status()
            self._say('info', f'steps {st["steps"]:,d} / {st["budget"]:,d}  best '
                              f'{st["best_value"]:.3f}  delta* {st["delta_star"]:.4f}  '
                              f'{st["steps_per_s"] / 1e6:.2f} M steps/s')

    # status and diagnostics -----------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """A copy of the run's status (the values /diagnostics reports)."""
        with self._lock:
            return dict(self._status)

    def _set_status(self, wake: bool = True, **values: Any) -> None:
        with self._lock:
            changed = 'state' in values and values['state'] != self._status['state']
            self._status.update(values)
        if (wake or changed) and not self._closing:
            try:
                self._wake.trigger()
            except Exception:  # noqa: BLE001 - the node is being destroyed: nothing to wake
                pass

    def diagnostics(self) -> DiagnosticArray:
        """The /diagnostics message of the current status."""
        st = self.status()
        status = DiagnosticStatus()
        status.level = DiagnosticStatus.ERROR if st['state'] == 'failed' else DiagnosticStatus.OK
        status.name = f'{self.get_name()}: training'
        status.hardware_id = self.problem.name
        status.message = st['message']
        values = {
            'state': st['state'], 'steps': st['steps'], 'budget': st['budget'],
            'best_value': float(st['best_value']), 'delta_star': float(st['delta_star']),
            'delta': float(st['delta']), 'achieved': st['delta_star'] <= st['delta'],
            'steps_per_s': float(st['steps_per_s']), 'generation': st['generation'],
            'episodes': st['episodes'], 'method': st['method'], 'seed': st['seed'],
            'served': self._served.source or 'none', 'out': self._out,
        }
        status.values = [KeyValue(key=k, value=str(v).lower() if isinstance(v, bool)
                                  else repr(v) if isinstance(v, float) else str(v))
                         for k, v in values.items()]
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [status]
        return msg

    def _publish_diagnostics(self) -> None:
        self._diag_pub.publish(self.diagnostics())

    def _say(self, level: str, text: str) -> None:
        """Log from any thread; after shutdown (rosout gone) to stderr."""
        if self.context.ok() and not self._closing:
            getattr(self.get_logger(), level)(text)
        else:
            import sys
            print(f'[{self.get_name()}] {text}', file=sys.stderr, flush=True)

    # shutdown -------------------------------------------------------------------------------

    def stop_training(self, timeout: float = JOIN_TIMEOUT_S) -> bool:
        """Ask a run to stop (it saves what it has) and wait for it; True once stopped."""
        self._stop.set()
        thread = self._thread
        if thread is not None and thread.is_alive():
            self._say('info', 'stopping the training run (saving the best so far)')
            thread.join(timeout)
            return not thread.is_alive()
        return True

    def destroy_node(self) -> None:
        """Stop the run cleanly (best policy and checkpoint written), then destroy the node."""
        self._closing = True
        if not self.stop_training():
            self._say('error', f'training did not stop within {JOIN_TIMEOUT_S} s')
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """``ros2 run sapga_ros trainer_node``."""
    return run_node(lambda: TrainerNode(), args)


if __name__ == '__main__':
    raise SystemExit(main())
