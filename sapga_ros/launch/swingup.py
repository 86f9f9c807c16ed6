"""``sapga launch swingup``: simulator + policy node + rosbag2 recorder for N episodes.

    sapga launch swingup --policy FILE --out DIR [--mode lockstep|realtime] [--episodes N]
                         [--problem P] [--delta D] [--n-step N] [--real-time-factor F]
                         [--engine E] [--namespace NS] [--remap FROM:=TO ...] [--ros-args ARGS...]

The problem is the policy file's; delta is ``--delta``, else the policy's training delta
(``meta.delta``), else the problem's default.  The order makes the recording whole and a
lockstep episode exact:

1. the recorder and the policy node start; the policy file goes to the policy node (its
   ``policy_file`` parameter);
2. the simulator starts (lockstep, silent: it waits for the recorder before its first
   episode starts, then at the first state without re-publishing it);
3. the launcher waits until the ROS graph joins them all (every topic has its publisher
   and subscribers) and the recorder's ``ready`` service says it hears every publisher of
   every recorded topic, then a settling moment;
4. the simulator is let go: in lockstep it re-publishes the waiting state, the policy
   answers it and the episodes run step by step; in realtime mode it switches to realtime
   (``mode``, ``real_time_factor``) and holds command 0 until the policy's first answer, as
   any realtime start does.  ``max_episodes`` = N stops the simulator after N episodes;
5. after the N-th episode end event, and once the bag on disk holds every message of the
   episodes (a busy recorder lags behind a lockstep episode), the nodes are stopped
   (Ctrl-C), the recorder finishes its bag, and a summary is printed: per episode end,
   steps, return and delta*, the bag, and in lockstep the offline evaluation of the same
   file (``sapga eval``), which must be equal.  The launch fails (exit 1) when an episode
   differs or the finished bag lacks a message of the episodes (``recording/verify.py``).
   Settings given through ``--ros-args -p`` that the offline evaluation also takes (the
   simulator's disturbance and its seed, the policy node's delay and planner) are
   honoured, each disturbed episode compared with the evaluation's episode of the same
   draws; with any other setting the launch says there is nothing to compare
   (``reference.py``).

The stack (``stack.py``) and the launch's own node (``launch_node.py``) are shared with
``train_deploy``.  ``--engine mujoco`` runs the MuJoCo robot (``sim_node -p engine:=mujoco``)
and gives the policy node its joint mapping and an effort array output; the recorder records
the effort array too, and there is no offline evaluation to compare (another engine).
``--namespace``, ``--remap`` and ``--ros-args`` go to every node
(``ros_args.py``).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

from sapga_ros.errors import SapgaError
from sapga_ros.evaluation.replan_settings import check_plannable
from sapga_ros.io.outputs import check_output_dir
from sapga_ros.launch.supervisor import Supervisor, launch_main
from sapga_ros.launch.launch_node import LaunchRos
from sapga_ros.launch.ros_args import RosOptions, add_ros_arguments
from sapga_ros.launch.reference import lockstep_reference, matches
from sapga_ros.launch.stack import (DeployStack, StackOptions, episode_lines,  # noqa: F401
                                    event_summary, offline_episode, same_episode)
from sapga_ros.policies.kinds import policy_delta
from sim_nodes.options import add_param
from sim_nodes.params import DELTA, N_STEP
from sim_nodes.problem import load_problem
from sim_nodes.ros.sim_settings import sim_parameters


# the swingup launch -------------------------------------------------------------------------

@dataclass
class SwingupResult:
    """What a swingup launch produced."""

    episodes: list[dict]            # the simulator's end events
    recordings: list[Path]
    offline: dict | None            # lockstep: the offline evaluation of the policy file
    equal: bool | None              # lockstep: every episode equals it
    recording_error: str | None = None  # why the bag is not whole, if it is not
    different: tuple[int, ...] = ()     # lockstep: the episodes that differ (1-based)
    no_reference: str = ''          # lockstep: why there is no offline evaluation to compare


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f'expected an integer >= 1, got {text!r}')
    return value


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='sapga launch swingup',
                                description='Run a policy file on the simulator and record '
                                            'the episodes to MCAP.')
    sim = {q.name: q for q in sim_parameters('acrobot')}
    p.add_argument('--policy', required=True, metavar='FILE', help='policy file')
    p.add_argument('--out', required=True, metavar='DIR', help='directory of the recording')
    add_param(p, replace(sim['mode'], default='lockstep'),
              help='lockstep (default; equals sapga eval) or realtime')
    p.add_argument('--episodes', type=positive_int, default=1, metavar='N',
                   help='episodes (default 1)')
    p.add_argument('--problem', help="problem (default: the policy file's; must match it)")
    add_param(p, DELTA, help="goal difficulty (default: the policy's training delta, else "
                             "the problem's)")
    add_param(p, N_STEP, help='MDP steps per episode (default: the problem\'s; e.g. 1200 = '
                              '60 s of an acrobot_hold episode)')
    add_param(p, sim['real_time_factor'], help='realtime mode: sim time / wall time '
                                               '(default 1)')
    add_param(p, sim['engine'], help='kernel (default) or mujoco: the MuJoCo robot, which '
                                     'the policy node drives through its joint mapping and '
                                     'an effort array')
    p.add_argument('--replan', action='store_true',
                   help='the policy node re-plans the policy\'s episode at every state '
                        '(decision-time planning; its settings through --ros-args -p '
                        'replan_fit:=X ...; compared with sapga eval --replan; a hold task '
                        'hands over to the classical LQR)')
    add_ros_arguments(p)
    return p


def run_swingup(args: argparse.Namespace, sup: Supervisor) -> SwingupResult:
    """The launch itself, under ``sup`` (which stops the nodes whatever happens)."""
    from sapga_ros.policies.runnable import load_policy
    problem = load_problem(args.problem) if args.problem else None
    policy = load_policy(Path(args.policy).resolve(), problem)   # checked before any start
    problem = policy.problem
    if args.replan:
        check_plannable(problem, '--replan')
    if args.replan and (args.delta is not None or args.n_step is not None):
        raise SapgaError('--replan plans for the policy\'s own delta and the problem\'s '
                         'episode length: no --delta or --n-step with it')
    check_output_dir(Path(args.out), '--out', parents=True)    # before any node starts
    opts = StackOptions(problem, Path(args.out).resolve(), policy_delta(policy, args.delta),
                        args.episodes, args.mode, args.real_time_factor, args.engine,
                        args.n_step, args.replan)
    sup.say(f'{problem.name}: policy {args.policy} ({len(policy)} exemplars), delta '
            f'{opts.delta}, {opts.episodes} episode(s) in {opts.mode} mode, recording to '
            f'{opts.out}' + (', on the MuJoCo robot' if opts.engine == 'mujoco' else ''))
    ros = LaunchRos(problem, RosOptions.of(args))
    try:
        with tempfile.TemporaryDirectory(prefix='sapga-launch-') as tmp:
            stack = DeployStack(sup, ros, opts, Path(tmp))
            stack.start()
            ros.set_parameters(sup, 'policy_node',
                               {'policy_file': str(Path(args.policy).resolve())})
            stack.start_sim()
            stack.wait_connected()
            stack.go()
            ends = stack.run_episodes()
            stack.wait_recorded(ends)
    finally:
        sup.stop()
        ros.close()
    result = SwingupResult(ends, stack.recordings(), None, None, stack.check_recording(ends))
    if opts.mode == 'lockstep' and opts.engine == 'kernel':   # MuJoCo is not the kernel
        ref = lockstep_reference(policy, opts.delta, opts.n_step, len(ends), opts.replan,
                                 ros.options.extra)
        if not ref.episodes:
            result.no_reference = ref.why or 'no episode ended'
        else:
            result.different = tuple(matches(ends, ref.episodes))
            result.offline = {**ref.episodes[0], 'by': ref.by, 'each': len(ref.episodes) > 1}
            result.equal = not result.different
    return result


def print_swingup(sup: Supervisor, result: SwingupResult) -> int:
    """Print the summary; 0, or 1 if a lockstep episode differs from the offline one."""
    lines = episode_lines(result.episodes)
    for path in result.recordings:
        lines.append(f'recording: {path}')
    if not result.recordings:
        lines.append("recording: none written (see the recorder's output)")
    if result.offline is not None:
        o = result.offline
        verdict = ('every lockstep episode is equal' if result.equal else
                   'DIFFERENT from lockstep episode(s) '
                   + ', '.join(str(k) for k in result.different))
        by = o.get('by', 'sapga eval')
        if o.get('each'):           # disturbed: each episode has its own draws
            lines.append(f'offline evaluation ({by}, each episode on its own draws): '
                         + verdict)
        else:
            lines.append(f'offline evaluation ({by}): return {o["return"]:.4f}, delta* '
                         f'{o["delta_star"]:.5f}, steps {o["steps"]}: ' + verdict)
    elif result.no_reference:
        lines.append(f'offline evaluation: none to compare ({result.no_reference})')
    if result.recording_error:
        lines.append(f'error: {result.recording_error}')
    sup.say('\n'.join(lines))
    return 0 if result.equal in (None, True) and not result.recording_error else 1


def main(argv: Sequence[str] | None = None) -> int:
    """``sapga launch swingup ...``; the exit code (see ``run_launch``)."""
    return launch_main(argv, build_parser(), run_swingup, print_swingup)


if __name__ == '__main__':
    sys.exit(main())
