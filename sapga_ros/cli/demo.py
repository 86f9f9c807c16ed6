"""The main job (``make demo``): evolve an Acrobot policy, deploy it through ROS 2, record and
summarise the episode.

    python -m sapga_ros.cli.demo --out DIR [--steps N] [--seed S] [--delta D] [--jobs J]

1. ``sapga launch train_deploy``: the trainer node runs SAP-GA (paper Table 2, experiment 2:
   acrobot, delta 0.02, 30 M steps, seed 0 by default) on every core; the policy node loads
   the best policy over the trainer's ``get_policy`` service; the simulator runs one episode
   in lockstep; the recorder writes it to MCAP; the ROS episode is compared with the offline
   evaluation of the served policy (they are equal, exactly).
2. ``sapga inspect``: the recording's summary, and its plot in ``DIR/episode.png``.

Exit status 0 when every stage worked, the ROS episode equals the offline one and the
policy reached the goal area S_delta; 1 otherwise, saying which.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Sequence

from sapga_ros.errors import SapgaError
from sapga_ros.launch.supervisor import LaunchError, Supervisor, exit_code
from sapga_ros.launch.train_deploy import add_run_arguments, run_train_deploy, summary_lines
from sim_nodes.problem import load_problem

PROBLEM = 'acrobot'
DELTA = 0.02             # paper Table 2, experiment 2
STEPS = 30_000_000       # seed 0 reaches delta* 0.0136 (its best policy 0.0183) within it


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='python -m sapga_ros.cli.demo', description=__doc__.split(
        '\n\n')[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--out', default='out', metavar='DIR',
                   help='policy, checkpoint, recording and plot go here (default out)')
    add_run_arguments(p, steps=STEPS, delta=DELTA)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo; the exit status."""
    from sapga_ros.cli.recordings import run_inspect

    args = build_parser().parse_args(argv)
    out = Path(args.out)
    start = time.monotonic()
    sup = Supervisor()
    launch_args = argparse.Namespace(out=str(out), problem=PROBLEM, steps=args.steps,
                                     seed=args.seed, delta=args.delta, jobs=args.jobs)
    sup.say(f'demo: {PROBLEM}, SAP-GA {args.steps:,d} steps, seed {args.seed}, delta '
            f'{args.delta}: train -> deploy over ROS 2 -> record -> inspect', 'demo')
    try:
        with sup, sup.handle_signals():
            result = run_train_deploy(launch_args, sup)
    except SapgaError as exc:
        sup.say(f'error: {exc}', 'demo')
        return exit_code(exc) if isinstance(exc, LaunchError) else 2
    sup.say('\n'.join(summary_lines(result)), 'demo')
    print(flush=True)
    if not result.recordings:
        sup.say('error: the recorder wrote no bag', 'demo')
        return 1
    recording = result.recordings[-1]
    plot = out / 'episode.png'
    code = run_inspect(str(recording), plot=str(plot))
    sys.stdout.flush()
    print(flush=True)
    problems = []
    if code != 0:
        problems.append(f'sapga inspect failed on {recording}')
    if not result.equal:
        problems.append('the ROS episode differs from the offline evaluation')
    if result.recording_error:
        problems.append(result.recording_error)
    if not result.episode['reached']:
        problems.append(f'the policy did not reach S_delta (delta* '
                        f'{result.episode["delta_star"]:.4f} > {args.delta}); try more '
                        '--steps')
    elapsed = time.monotonic() - start
    if problems:
        sup.say(f'demo FAILED after {elapsed:.0f} s: ' + '; '.join(problems), 'demo')
        return 1
    e = result.episode
    problem = load_problem(PROBLEM)
    seconds = e['steps'] * problem.dt * problem.substeps
    sup.say(f'demo done in {elapsed:.0f} s: the evolved policy swings the acrobot up into '
            f'S_delta (delta* {e["delta_star"]:.4f} <= {args.delta}) in {e["steps"]} steps '
            f'({seconds:.2f} s), return {e["return"]:.3f}, identical over ROS 2 and '
            f'offline.\n  policy:    {result.policy_file}\n  recording: {recording}\n'
            f'  plot:      {plot}', 'demo')
    return 0


if __name__ == '__main__':
    sys.exit(main())
