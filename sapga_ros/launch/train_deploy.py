"""``sapga launch train_deploy``: evolve a policy in the trainer node, deploy it over the
service, run the episode in lockstep, record it, and compare with the offline evaluation.

    sapga launch train_deploy --out DIR [--problem acrobot] [--steps N] [--seed S]
                              [--delta D] [--jobs J]
                              [--namespace NS] [--remap FROM:=TO ...] [--ros-args ARGS...]

1. The trainer node (``train_on_start``; policy ``DIR/policy.json``, checkpoints in
   ``DIR/checkpoint``), the recorder and the policy node (no policy) start; the trainer
   reports on ``/diagnostics`` and logs its progress.
2. When the trainer's state is ``done``, the launcher calls the policy node's
   ``load_policy``, which fetches the best policy from the trainer's ``get_policy``; then the
   simulator starts (lockstep, one episode, its first state once the recorder is ready), and
   when the graph joins every node it re-publishes its waiting state, the policy answers it
   and the episode runs in lockstep.
3. After the episode's end event every node is stopped, the recorder finishes its bag,
   and the summary compares the ROS episode (return, delta*, steps) with the offline
   evaluation of the policy the trainer served: in lockstep they are equal, exactly.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Sequence

from sapga_ros.io.outputs import check_output_dir
from sapga_ros.launch.supervisor import LaunchError, Supervisor, launch_main
from sapga_ros.launch.ros_args import RosOptions, add_ros_arguments
from sapga_ros.launch.swingup import (DeployStack, LaunchRos, StackOptions, episode_lines,
                                      event_summary, offline_episode, same_episode)
from sapga_ros.training.loop import TrainConfig
from sim_nodes.options import add_param
from sim_nodes.params import declared
from sim_nodes.problem import load_problem

TRAIN_TIMEOUT_S = None   # training takes as long as its budget: no limit (Ctrl-C stops it)


@dataclass
class TrainDeployResult:
    """What a train_deploy launch produced."""

    policy_file: Path               # the trainer's best policy file
    trainer: dict[str, str]         # the trainer's last diagnostics key values
    episode: dict                   # the ROS episode: return, delta_star, steps, reached
    offline: dict                   # the served policy's offline evaluation
    equal: bool
    recordings: list[Path]
    end_event: dict
    recording_error: str | None = None  # why the bag is not whole, if it is not


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='sapga launch train_deploy',
                                description='Evolve a policy in the trainer node, deploy it to '
                                            'the policy node over the service, run and record '
                                            'one lockstep episode.')
    p.add_argument('--out', required=True, metavar='DIR',
                   help='directory of the policy, checkpoint and recording')
    p.add_argument('--problem', default='acrobot', help='problem (default acrobot)')
    add_run_arguments(p)
    add_ros_arguments(p)
    return p


def add_run_arguments(p: argparse.ArgumentParser, **defaults: Any) -> None:
    """--steps, --seed, --delta, --jobs: the trainer's declarations (other ``defaults``)."""
    for q in declared(TrainConfig):
        if q.name in ('steps', 'seed', 'delta', 'jobs'):
            add_param(p, replace(q, default=defaults.get(q.name, q.default)))


def run_train_deploy(args: argparse.Namespace, sup: Supervisor) -> TrainDeployResult:
    """The launch itself, under ``sup`` (which stops the nodes whatever happens)."""
    from sapga_ros.policies.runnable import policy_from_json
    problem = load_problem(args.problem)
    check_output_dir(Path(args.out), '--out', parents=True)    # before any node starts
    out = Path(args.out).resolve()
    delta = problem.resolve('delta', args.delta)
    policy_file = out / 'policy.json'
    opts = StackOptions(problem, out, delta, episodes=1, mode='lockstep')
    sup.say(f'{problem.name}: training {args.steps:,d} steps (seed {args.seed}, delta '
            f'{delta}) in the trainer node, then one lockstep episode recorded to {out}')
    ros = LaunchRos(problem, RosOptions.of(args))
    try:
        with tempfile.TemporaryDirectory(prefix='sapga-launch-') as tmp:
            stack = DeployStack(sup, ros, opts, Path(tmp))
            stack.start()
            stack.spawn('trainer', 'trainer_node', {
                'problem': problem.name, 'method': 'sapga', 'delta': delta,
                'steps': args.steps, 'seed': args.seed, 'jobs': args.jobs,
                'out': str(policy_file), 'checkpoint': str(out / 'checkpoint'),
                'train_on_start': True})
            node = ros.node

            def trained() -> dict[str, str] | None:
                status = node.trainer
                if status and status.get('state') == 'failed':
                    raise LaunchError(f'trainer: {status.get("message")}')
                return status if status and status.get('state') in ('done', 'stopped') else None

            trainer = sup.wait(trained, timeout=TRAIN_TIMEOUT_S, what='the training run')
            sup.say(f'trainer: {trainer["message"]}')
            served = ros.trigger(sup, 'trainer_node/get_policy')
            if not served.success:
                raise LaunchError(f'trainer serves no policy: {served.message}')
            policy = policy_from_json(served.message, problem, 'get_policy')
            loaded = ros.trigger(sup, 'policy_node/load_policy')
            if not loaded.success:
                raise LaunchError(f'policy node did not load the policy: {loaded.message}')
            sup.say(f'policy node: {loaded.message}')
            stack.start_sim()
            stack.wait_connected()
            stack.go()
            end = stack.run_episodes()[0]
            stack.wait_recorded([end])
    finally:
        sup.stop()
        ros.close()
    offline = offline_episode(policy, delta)
    episode = event_summary(end)
    return TrainDeployResult(policy_file, trainer, episode, offline,
                             same_episode(episode, offline), stack.recordings(), end,
                             stack.check_recording([end]))


def summary_lines(result: TrainDeployResult) -> list[str]:
    """The summary of a train_deploy run as text lines."""
    t, e, o = result.trainer, result.episode, result.offline
    lines = [f'trained: {t.get("steps")} steps, best value {t.get("best_value")}, run delta* '
             f'{t.get("delta_star")} (delta {t.get("delta")}, achieved {t.get("achieved")})',
             f'policy:  {result.policy_file}']
    lines += episode_lines([result.end_event])
    lines.append(f'{"":>7} {"offline":<10} {o["steps"]:>5} {o["return"]:>12.4f} '
                 f'{o["delta_star"]:>9.5f}   (served policy, batch evaluator)')
    lines.append('ROS episode == offline evaluation: '
                 + ('yes, exactly (return, delta*, steps)' if result.equal else
                    f'NO: ROS {e} vs offline {o}'))
    lines += [f'recording: {p}' for p in result.recordings] or [
        "recording: none written (see the recorder's output)"]
    if result.recording_error:
        lines.append(f'error: {result.recording_error}')
    return lines


def report(sup: Supervisor, result: TrainDeployResult) -> int:
    """Print the summary; 0 if the ROS episode equals the offline one and the bag is whole."""
    sup.say('\n'.join(summary_lines(result)))
    return 0 if result.equal and not result.recording_error else 1


def main(argv: Sequence[str] | None = None) -> int:
    """``sapga launch train_deploy ...``; the exit code (see ``run_launch``)."""
    return launch_main(argv, build_parser(), run_train_deploy, report)


if __name__ == '__main__':
    sys.exit(main())
