"""Foxglove layouts, one per problem, generated from its YAML (``msg_configs/foxglove/``).

``layout(problem)`` is a Foxglove layout (Layouts, Import from file) for a live run or a
recording of that problem:

* a 3D panel drawing ``markers`` with the markers' own frame (``ros.frame_id``) as its
  display frame (``followTf``), looking at the x-z plane (the package publishes no TF:
  every marker is in that one frame);
* a plot of every state coordinate at its real place in ``joint_states`` (the ``state:``
  layout: ``position`` or ``velocity`` of its joint), named after the coordinate;
* a plot of the commanded effort (``command_stamped``) and the applied one
  (``joint_states.effort`` of the actuated joint);
* the episode events as raw messages.

One time base: every plotted series is timed by its ``header.stamp`` (sim time).  The
headerless topics (``reward``, ``exemplar_index``: ``std_msgs``) are not plotted, since
Foxglove could place them only by receive time, a different clock; an episode's return is in
its end event.  ``python -m sapga_ros.viz.foxglove [--out DIR]`` writes
``<problem>.json`` for every problem; ``tests/test_foxglove.py`` checks the committed files
are what this writes.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from sim_nodes.problem import Problem, load_problem, problem_names
from sim_nodes.ros.common import JointStateLayout, topic_names

TIMESTAMP = 'headerStamp'      # the one time base of every plotted series
LAYOUT_DIR = Path(__file__).resolve().parents[2] / 'msg_configs' / 'foxglove'


def _plot(title: str, series: list[tuple[str, str]]) -> dict[str, Any]:
    return {'title': title,
            'paths': [{'value': path, 'label': label, 'enabled': True,
                       'timestampMethod': TIMESTAMP} for path, label in series],
            'showXAxisLabels': True, 'showYAxisLabels': True, 'showLegend': True,
            'legendDisplay': 'floating', 'showPlotValuesInLegend': True, 'isSynced': True,
            'xAxisVal': 'timestamp', 'sidebarDimension': 240}


def _three_d(markers: str, frame: str) -> dict[str, Any]:
    return {
        'cameraState': {'perspective': True, 'distance': 7, 'phi': 90, 'thetaOffset': 0,
                        'targetOffset': [0, 0, 0.3], 'target': [0, 0, 0],
                        'targetOrientation': [0, 0, 0, 1], 'fovy': 45, 'near': 0.01,
                        'far': 5000},
        'followMode': 'follow-none', 'followTf': frame,
        'scene': {'enableStats': False, 'backgroundColor': '#ffffff'},
        'transforms': {}, 'topics': {markers: {'visible': True}},
        'layers': {'grid': {'visible': True, 'frameLocked': True, 'label': 'Grid',
                            'instanceId': 'grid', 'layerId': 'foxglove.Grid',
                            'frameId': frame, 'size': 6, 'divisions': 12, 'lineWidth': 1,
                            'color': '#24248e40', 'position': [0, 0, 0],
                            'rotation': [90, 0, 0], 'order': 1}}}


def layout(problem: Problem) -> dict[str, Any]:
    """The Foxglove layout of ``problem`` (see the module docstring)."""
    js = JointStateLayout(problem)
    topics = {role: f'/{name}' for role, name in topic_names(problem).items()}
    state = topics['state']
    where = {d: f'position[{j}]' for d, j in js.position}
    where.update({d: f'velocity[{j}]' for d, j in js.velocity})
    names = problem.state_names
    series = [(f'{state}.{where[d]}', names[d]) for d in sorted(where)]
    efforts = [(f'{topics["command_stamped"]}.effort[0]', 'commanded effort'),
               (f'{state}.effort[{js.actuator}]', f'applied effort ({problem.actuator_joint})')]
    return {
        'configById': {
            '3D!sapga': _three_d(topics['markers'], js.frame_id),
            'Plot!state': _plot(f'{problem.name} state ({state})', series),
            'Plot!effort': _plot('Effort', efforts),
            'RawMessages!events': {'diffEnabled': False, 'diffMethod': 'custom',
                                   'diffTopicPath': '', 'showFullMessageForDiff': False,
                                   'topicPath': f'{topics["event"]}.data'}},
        'globalVariables': {}, 'userNodes': {}, 'playbackConfig': {'speed': 1},
        'layout': {'first': '3D!sapga',
                   'second': {'first': 'Plot!state',
                              'second': {'first': 'Plot!effort',
                                         'second': 'RawMessages!events',
                                         'direction': 'column', 'splitPercentage': 60},
                              'direction': 'column', 'splitPercentage': 50},
                   'direction': 'row', 'splitPercentage': 55}}


def layout_text(problem: Problem) -> str:
    """The layout file's text: JSON, indented, one trailing newline."""
    return json.dumps(layout(problem), indent=2, allow_nan=False) + '\n'


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m sapga_ros.viz.foxglove',
                                     description='write <problem>.json, the Foxglove layout '
                                                 'of every problem')
    parser.add_argument('--out', default=str(LAYOUT_DIR), metavar='DIR',
                        help='folder to write to (default msg_configs/foxglove)')
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in problem_names():
        path = out / f'{name}.json'
        path.write_text(layout_text(load_problem(name)), encoding='utf-8')
        print(path)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
