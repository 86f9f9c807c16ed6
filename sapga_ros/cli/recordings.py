"""``sapga inspect`` and ``sapga bag``: the recording commands.

    sapga inspect BAG_OR_FILE [--json] [--plot OUT.png] [--episode N]
    sapga bag reindex BAG_OR_FILE

``inspect`` summarises a rosbag2 bag directory or one MCAP file (``recording/inspect.py``)
and plots one episode (``viz/episode_plot.py``); a recording cut short is summarised as far
as it can be read, with a warning on stderr.  ``bag reindex`` completes a killed recording,
like ``ros2 bag reindex`` (``recording/repair.py``), skipping damaged chunks and saying what
they held; it exits 1 when messages were lost.  Unreadable input, an episode not in
the recording, a plot file that cannot be written (a directory, a missing folder): one line
on stderr, exit status 2.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sapga_ros.cli.args import check_output_file
from sapga_ros.errors import McapError, SapgaError
from sapga_ros.io.jsonfile import dumps

EXIT_USAGE = 2


def add_inspect_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('path', metavar='BAG', help='bag directory or .mcap file')
    parser.add_argument('--json', action='store_true', help='print one JSON object')
    parser.add_argument('--plot', metavar='OUT.png', help='plot one episode to a PNG file')
    parser.add_argument('--episode', type=int, metavar='N',
                        help='episode to plot (default: the one with the highest return)')


def add_bag_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest='bag_command', required=True, metavar='VERB')
    r = sub.add_parser('reindex', help='complete a killed or damaged recording (summary, '
                                       'footer, metadata.yaml), like ros2 bag reindex; a '
                                       'damaged chunk is skipped and its loss reported '
                                       '(exit 1)')
    r.add_argument('path', metavar='BAG', help='bag directory or .mcap file')


def inspect_summary(path: str, plot: str | None = None, episode: int | None = None
                    ) -> dict:
    """The summary of a recording (and its plot, if asked); McapError if unreadable.  The
    recording is streamed (``recording/inspect.py``): any number of messages."""
    from sapga_ros.recording.inspect import Picker, fmt, inspect_path

    if plot:
        check_output_file(Path(plot), '--plot')
    picker = Picker(episode) if plot else None
    try:
        summary, rec, problem = inspect_path(path, picker)
    except McapError:
        raise
    except Exception as exc:  # noqa: BLE001 - no file content may crash the CLI
        raise McapError(f'{path}: messages do not match their roles '
                        f'({type(exc).__name__}: {exc})'[:300]) from exc
    if summary['error']:
        print(f'warning: {summary["error"]}; summarising the {summary["message_count"]} '
              'messages read', file=sys.stderr)
    if plot:
        from sapga_ros.viz.episode_plot import plot_episode
        if problem is None:
            raise McapError(f'{path}: cannot plot: {summary["problem_error"]}')
        chosen, ep = picker.chosen()
        title = (f'{problem.name}: episode {fmt(ep["episode"], "d")}, {ep["end"]}, '
                 f'return {fmt(ep["return"], ".2f")}, delta* {fmt(ep["delta_star"], ".4f")}')
        try:
            plot_episode(chosen, problem, plot, title, ep['goal_delta'])
        except OSError as exc:
            raise McapError(f'{plot}: cannot write the plot ({exc.strerror})') from exc
        summary['plot'] = {'file': plot, 'episode': ep['episode']}
    return summary


def run_inspect(path: str, json_out: bool = False, plot: str | None = None,
                episode: int | None = None) -> int:
    """Print the summary of a recording (text or one JSON object); the exit status."""
    from sapga_ros.recording.inspect import fmt, format_summary
    try:
        summary = inspect_summary(path, plot, episode)
    except SapgaError as exc:
        print(f'sapga inspect: error: {exc}', file=sys.stderr)
        return EXIT_USAGE
    if json_out:
        print(dumps(summary, default=str))
    else:
        print(format_summary(summary))
        if plot:
            print(f'plot:      {plot} (episode {fmt(summary["plot"]["episode"], "d")})')
    return 0


def cmd_inspect(args: argparse.Namespace) -> int:
    return run_inspect(args.path, json_out=args.json, plot=args.plot, episode=args.episode)


def cmd_bag(args: argparse.Namespace) -> int:
    """Exit status 0: no damage found; 1: damage found (what it cost is reported), or a file
    held nothing readable (left as it was); 2: not a recording."""
    from sapga_ros.recording.repair import reindex

    result = reindex(args.path)
    for r in result.files:
        if r.action != 'intact' or r.damage:
            print(r.report(), file=sys.stderr if r.loses else sys.stdout)
    what = (f'repaired {", ".join(p.name for p in result.repaired)}' if result.repaired
            else 'every storage file was complete' if not result.lost
            else 'nothing could be repaired')
    tail = '; wrote metadata.yaml' if result.metadata_written else ''
    print(f'{result.path}: {what}{tail}; {result.messages} messages')
    return 1 if result.lost else 0
