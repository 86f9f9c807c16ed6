"""Trainer node: SAP-GA (or the Q-learning baseline, or CMA-ES) offline, served over ROS 2.

Training runs in a background thread through the one training loop (``training.loop.train``,
with the fast batch evaluator), never over ROS topics; the node reports progress on
``/diagnostics``, writes checkpoints and the best policy file, and serves the best policy so
far on ``get_policy``.  The best policy, its log and the checkpoint are saved at least every
``checkpoint_seconds`` (30 s) of a run, so a killed node loses at most that.

Parameters (msg_configs/params/trainer_node.yaml; docs/ros_interface.md has the table):
the declarations of the config dataclasses (``sapga_ros.nodes.trainer_params``) -- the
run's ``method``, ``delta`` (default: the problem's ``episode.delta``), ``steps``, ``seed``,
``jobs``, ``checkpoint_seconds``, ``checkpoint_every``, ``resume``, SAP-GA's ``n_pop``,
``n_child``, ``l_min``, ``l_max``, ``style``, ``variant``, Q-learning's ``chunk_steps``,
CMA-ES's ``exemplars``, ``sigma0``, ``popsize``, the node's ``out``, ``train_on_start``,
``policy_file``, ``diagnostics_period``,
``log_period`` -- plus ``problem`` (read-only) and ``checkpoint`` ('': ``<out without
suffix>.ckpt`` beside ``out``, none without ``out``).
``out`` and the checkpoint directory must be in existing folders (a run is refused
otherwise).  A change applies to the next run.

Services (std_srvs/Trigger, the node's own: ``/trainer_node/get_policy``, ...).  They run on
a multi-threaded executor in a reentrant group with a deep request queue, so a burst of
requests is answered in full: a ``stop`` waiting for its round holds no other request, and
``train`` and ``stop`` are serialised (one run at a time; a stop answers about its run):

* ``get_policy``: ``message`` = the JSON document of the most recent of: the
  ``policy_file`` (one that cannot be served at start stops the node with one line naming
  it, exit 2), the best policy of the current or last SAP-GA run.  ``success`` false with
  the reason when there is none, and once a Q-learning run has started (a Q-table is no
  exemplar policy: the policy node cannot run it; ``sapga eval`` runs its ``out`` file).
* ``train``: starts a run with the current parameters; refused while one is running.
* ``stop``: ends the run after its current round (a SAP-GA generation, a Q-learning chunk
  of ``chunk_steps``), saves the best policy, log and checkpoint, and answers once they are
  written (``message``: what was saved where), state ``stopped``; ``success`` false when no
  run is going on.  The service waits for the round (at most ``STOP_WAIT_S``).

``/diagnostics`` (``nodes/trainer_status.py``; one status named ``<node>: training``):
``state`` idle | training | stopped | done | failed and the run's progress; published every
``diagnostics_period`` and at once when the state changes.  A failed run (one line in the
message and the log) leaves the node ready for the next.

A managed (lifecycle) node: with ``managed`` false (the default) it configures and activates
itself at start, as above; with ``managed`` true it starts unconfigured and its services
refuse (``success`` false, naming the state) until it is active: *configure* checks the run
parameters and loads ``policy_file`` (a failure is one error line and leaves the node
unconfigured), *activate* answers the services (and starts a run with ``train_on_start``),
*deactivate* stops a run as ``stop`` does and refuses the services again, *cleanup* forgets
the served policy, *shutdown* stops a run.

Shutdown (Ctrl-C, SIGTERM) stops a run as ``stop`` does and still writes the best policy so
far and the checkpoint.  (Over 300 lines: the node's services, parameter callbacks and run
supervision in one place; the run itself, its status and its parameters are
``trainer_run.py``, ``trainer_status.py`` and ``trainer_params.py``.)
"""
from __future__ import annotations

import math
import sys
import threading
from dataclasses import dataclass
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from std_srvs.srv import Trigger

from sapga_ros.errors import ConfigError, SapgaError
from sim_nodes.ros.common import run_node, steady_clock
from sapga_ros.nodes.trainer_params import PARAMETERS, check_setting, train_config
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.runnable import load_policy
from sapga_ros.nodes.trainer_run import RunHooks, TrainingRun
from sapga_ros.nodes.trainer_status import RunStatus, diagnostics
from sapga_ros.training.loop import TrainConfig
from sapga_ros.optim.sapga import memory_problem
from sim_nodes.problem import Problem, load_problem
from sim_nodes.ros.params import declare

JOIN_TIMEOUT_S = 120.0  # [s] shutdown waits this long for the run to stop and save
STOP_WAIT_S = 60.0      # [s] the stop service waits this long for the round to end
SERVICE_QOS = QoSProfile(depth=1000)    # requests queued at most (reliable, volatile)
SERVICE_THREADS = 4     # executor threads: stops that wait for the round leave the others
QL_NOT_SERVABLE = ('method ql learns a Q-table (sapga-qtable/1), not an exemplar policy: the '
                   'policy node cannot run it (evaluate the out file with `sapga eval`; '
                   'train with method sapga or cmaes to deploy)')


@dataclass(frozen=True)
class Served:
    """What ``get_policy`` answers: a policy and where it came from, or why there is none."""

    policy: ExemplarPolicy | None
    source: str
    reason: str = ''


class TrainerNode(LifecycleNode):
    """Trains in a background thread; reports, saves and serves the best policy."""

    def __init__(self, node_name: str = 'trainer_node', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        first = declare(self, PARAMETERS[:2])
        self.problem: Problem = load_problem(first['problem'])
        self.managed = bool(first['managed'])
        self.active = False
        values = declare(self, PARAMETERS[2:], self.problem)
        reason = memory_problem(values['n_pop'], values['n_child'], values['l_max'])
        if reason:
            raise ConfigError(f'{self.get_name()}: {reason}')

        self._run: TrainingRun | None = None
        self._start_lock = threading.Lock()
        self._closing = False
        self._served = Served(None, '', 'no policy yet: no training run has found one (call '
                                        'train, or set train_on_start or policy_file)')
        self._status = RunStatus(self.get_parameter('delta').value,
                                 self.get_parameter('method').value,
                                 self.get_parameter('seed').value)
        self._out = ''                  # the policy file of the current or last run
        policy_file = self.get_parameter('policy_file').value
        if policy_file and not self.managed:
            try:
                self._serve_file(policy_file)
            except SapgaError as exc:        # a user error at start: one line, exit 2
                raise ConfigError(f'{self.get_name()}: policy_file: {exc}') from None

        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # A stop waits for the round to end; with the executable's multi-threaded executor
        # and a reentrant group the other requests are answered meanwhile, and a deep
        # request queue keeps a burst of them until they are (none goes unanswered).
        services = {'qos_profile': SERVICE_QOS, 'callback_group': ReentrantCallbackGroup()}
        self._get_srv = self.create_service(Trigger, '~/get_policy', self._on_get_policy,
                                            **services)
        self._train_srv = self.create_service(Trigger, '~/train', self._on_train, **services)
        self._stop_srv = self.create_service(Trigger, '~/stop', self._on_stop, **services)
        # the training thread wakes the executor to publish a state change at once
        self._wake = self.create_guard_condition(self._publish_diagnostics)
        self._diag_timer = self.create_timer(self.get_parameter('diagnostics_period').value,
                                             self._publish_diagnostics, clock=steady_clock())
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        if self.managed:
            self.get_logger().info(f'{self.problem.name} trainer, managed: unconfigured, '
                                   'waiting for the configure transition')
            return
        message = self._serve_requests()
        if message:
            raise ConfigError(f'{self.get_name()}: cannot train: {message}')
        self.trigger_configure()
        self.trigger_activate()

    def _serve_requests(self) -> str:
        """Answer the services from now on; start a run with ``train_on_start``.  Why that
        run could not start ('' if it did, or none was asked for)."""
        self.active = True
        if self.get_parameter('train_on_start').value:
            ok, message = self.start_training()
            self.active = ok
            if not ok:
                return message              # the refusal is the only line
        self.get_logger().info(f'{self.problem.name} trainer: get_policy, train and stop '
                               'ready')
        return ''

    # lifecycle (managed) --------------------------------------------------------------------

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.managed:
            try:
                self.train_config()
                policy_file = self.get_parameter('policy_file').value
                if policy_file:
                    self._serve_file(policy_file)
            except (SapgaError, ValueError) as exc:
                self.get_logger().error(f'configure failed, still unconfigured: '
                                        f'{" ".join(str(exc).split())}'[:500])
                return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.managed and (message := self._serve_requests()):
            self.get_logger().error(f'activate failed: cannot train: {message}')
            return TransitionCallbackReturn.FAILURE
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        if not self.stop_training():
            self._say('error', f'training did not stop within {JOIN_TIMEOUT_S} s')
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._served = Served(None, '', 'no policy yet: the node was cleaned up')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self.stop_training()
        return TransitionCallbackReturn.SUCCESS

    def _refused(self, response: Trigger.Response) -> Trigger.Response | None:
        """The answer of a service while the node is not active (None when it is)."""
        if self.active:
            return None
        label = self._state_machine.current_state[1]
        response.success, response.message = False, (f'the trainer is {label}: activate it '
                                                     'first (managed)')
        return response

    # configuration --------------------------------------------------------------------------

    def train_config(self) -> TrainConfig:
        """The run the current parameters describe (``SapgaError`` if inconsistent)."""
        return train_config(lambda key: self.get_parameter(key).value, self.problem.name)

    def _serve_file(self, path: str) -> None:
        policy = load_policy(path, self.problem)   # PolicyFileError names what is wrong
        self._served = Served(policy, f'file {path}')
        self.get_logger().info(f'serving {path} ({len(policy)} exemplars) until training '
                               'finds a best policy')

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        given = {param.name: param.value for param in params}
        counts = [given.get(k, self.get_parameter(k).value)
                  for k in ('n_pop', 'n_child', 'l_max')]
        for param in params:
            reason = check_setting(param.name, param.value)
            if reason is None and param.name in ('n_pop', 'n_child', 'l_max'):
                reason = memory_problem(*counts)
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
        if refused := self._refused(response):
            return refused
        served = self._served   # one read: the training thread may replace it
        if served.policy is None:
            response.success, response.message = False, served.reason
        else:
            response.success, response.message = True, served.policy.to_json()
        return response

    def _on_train(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        if refused := self._refused(response):
            return refused
        response.success, response.message = self.start_training()
        return response

    def _on_stop(self, request: Trigger.Request, response: Trigger.Response
                 ) -> Trigger.Response:
        if refused := self._refused(response):
            return refused
        with self._start_lock:      # no run starts before this one's stop is answered
            return self._stop(response)

    def _stop(self, response: Trigger.Response) -> Trigger.Response:
        if not self.training:
            st = self.status()
            response.success = False
            response.message = f'no training run in progress (state {st["state"]})'
            return response
        if not self.stop_training(STOP_WAIT_S):
            response.success = True
            response.message = (f'stopping: the current round takes longer than {STOP_WAIT_S} '
                                's; /diagnostics reports state stopped once it is saved')
            return response
        st = self.status()
        response.success = st['state'] in ('stopped', 'done')
        response.message = st['message']
        return response

    @property
    def training(self) -> bool:
        """A run is in progress."""
        return self._run is not None and self._run.alive

    @property
    def history(self) -> list[dict]:
        """The log rows of the current or last run."""
        return self._run.history if self._run is not None else []

    def start_training(self) -> tuple[bool, str]:
        """Start a run with the current parameters; (started, message).  Two requests at
        once (the services run on several threads) start one run."""
        with self._start_lock:
            return self._start_training()

    def _start_training(self) -> tuple[bool, str]:
        if self.training and self.status()['state'] != 'training':
            # done, stopped or failed is published: the thread is only logging it; a train
            # call that saw the state must not be refused as "already training"
            self._run.stop(JOIN_TIMEOUT_S)
        if self.training:
            st = self.status()
            return False, (f'already training ({st["method"]}, {st["steps"]} of '
                           f'{st["budget"]} steps); wait for state done, or call stop')
        if self._closing:
            return False, 'shutting down'
        try:
            config = self.train_config()
        except (SapgaError, ValueError) as exc:
            return False, str(exc)
        out = self._out = self.get_parameter('out').value
        if config.method == 'ql':
            self._served = Served(None, 'ql run', QL_NOT_SERVABLE)
        self._set_status(state='training', steps=0, budget=config.steps,
                         best_value=-math.inf, delta_star=math.inf, delta=config.delta,
                         steps_per_s=0.0, generation=0, episodes=0, method=config.method,
                         seed=config.seed, message='training',
                         checkpoint=config.checkpoint or '')
        final = self._serve if config.method != 'ql' else lambda policy: None
        hooks = RunHooks(best=self._serve, result=final, changed=self._set_status,
                         say=self._say,
                         log_period=lambda: self.get_parameter('log_period').value)
        self._run = TrainingRun(config, out, self._status, hooks)
        self._run.start()
        text = (f'training started: {config.problem} {config.method}, delta {config.delta}, '
                f'{config.steps} steps, seed {config.seed}'
                + (' (resumed)' if config.resume else ''))
        self.get_logger().info(text)
        return True, text

    def _serve(self, policy: ExemplarPolicy) -> None:
        self._served = Served(policy, 'training')

    # status and diagnostics -----------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """A copy of the run's status (the values /diagnostics reports)."""
        return self._status.snapshot()

    def _set_status(self, **values: Any) -> None:
        """Update the status (if given) and publish it at once."""
        self._status.update(**values)
        if not self._closing:
            try:
                self._wake.trigger()
            except Exception:  # noqa: BLE001 - the node is being destroyed: nothing to wake
                pass

    def diagnostics(self) -> DiagnosticArray:
        """The /diagnostics message of the current status."""
        msg = diagnostics(self.get_name(), self.problem.name, self.status(),
                          self._served.source, self._out)
        msg.header.stamp = self.get_clock().now().to_msg()
        return msg

    def _publish_diagnostics(self) -> None:
        self._diag_pub.publish(self.diagnostics())

    def _say(self, level: str, text: str) -> None:
        """Log from any thread; after shutdown (rosout gone) to stderr.  Each severity has
        its own call (rclpy refuses a second severity from one call site)."""
        try:
            if not self.context.ok() or self._closing:
                raise RuntimeError('shut down')
            logger = self.get_logger()
            if level == 'error':
                logger.error(text)
            elif level == 'warning':
                logger.warning(text)
            else:
                logger.info(text)
        except Exception:  # noqa: BLE001 - a log line must never end the training thread
            print(f'[{self.get_name()}] {text}', file=sys.stderr, flush=True)

    # shutdown -------------------------------------------------------------------------------

    def stop_training(self, timeout: float = JOIN_TIMEOUT_S) -> bool:
        """Ask a run to stop (it saves what it has) and wait for it; True once stopped."""
        run = self._run
        if run is not None and run.alive:
            self._say('info', 'stopping the training run after this round (saving the best '
                              'so far)')
            return run.stop(timeout)
        return True

    def destroy_node(self) -> None:
        """Stop the run cleanly (best policy and checkpoint written), then destroy the node."""
        self._closing = True
        if not self.stop_training():
            self._say('error', f'training did not stop within {JOIN_TIMEOUT_S} s')
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """``ros2 run sapga_ros trainer_node``."""
    return run_node(lambda: TrainerNode(), args, parameters=lambda: PARAMETERS,
                    name='trainer_node',
                    executor=lambda node: MultiThreadedExecutor(num_threads=SERVICE_THREADS))


if __name__ == '__main__':
    raise SystemExit(main())
