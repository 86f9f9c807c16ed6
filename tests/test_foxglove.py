"""The Foxglove layouts (sapga_ros/viz/foxglove.py, msg_configs/foxglove/<problem>.json): one
per problem, as generated from its YAML; every plotted series is a real field of a message
the nodes publish, read back from such a message, timed by its header stamp; the 3D panel's
display frame is the markers' frame."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from sapga_ros.viz.foxglove import LAYOUT_DIR, layout, layout_text
from sim_nodes.problem import load_problem, problem_names
from sim_nodes.ros.commands import StampedCommand
from sim_nodes.ros.common import JointStateLayout, topic_names
from sim_nodes.ros.markers import PendulumMarkers

PATH = re.compile(r'^(/\w+)\.(position|velocity|effort)\[(\d+)\]$')


def leaves(node):
    return [node] if isinstance(node, str) else leaves(node['first']) + leaves(node['second'])


@pytest.mark.parametrize('name', problem_names())
def test_the_committed_layout_is_the_generated_one(name):
    path = LAYOUT_DIR / f'{name}.json'
    assert path.read_text(encoding='utf-8') == layout_text(load_problem(name)), (
        f'{path} is stale: python -m sapga_ros.viz.foxglove')


@pytest.mark.parametrize('name', problem_names())
def test_every_plotted_series_reads_its_field_from_the_published_messages(name):
    problem = load_problem(name)
    doc = layout(problem)
    panels = doc['configById']
    assert sorted(leaves(doc['layout'])) == sorted(panels)
    js = JointStateLayout(problem)
    topics = {role: f'/{t}' for role, t in topic_names(problem).items()}
    state = np.arange(1.0, problem.dim + 1.0) / 7.0        # every coordinate distinct
    messages = {topics['state']: js.to_msg(state, effort=0.625, stamp=5),
                topics['command_stamped']: StampedCommand(problem).fill(0.375, 5)}
    plotted = {}
    for panel in panels.values():
        for series in panel.get('paths', []):
            assert series['timestampMethod'] == 'headerStamp'     # one time base
            topic, field, index = PATH.match(series['value']).groups()
            plotted[series['label']] = getattr(messages[topic], field)[int(index)]
    for d, coordinate in enumerate(problem.state_names):
        assert plotted.pop(coordinate) == state[d]               # its real place
    assert plotted.pop('commanded effort') == 0.375
    assert plotted.pop(f'applied effort ({problem.actuator_joint})') == 0.625
    assert not plotted
    assert panels['RawMessages!events']['topicPath'] == f'{topics["event"]}.data'


@pytest.mark.parametrize('name', problem_names())
def test_the_3d_panel_shows_the_markers_in_their_own_frame(name):
    problem = load_problem(name)
    three_d = layout(problem)['configById']['3D!sapga']
    topics = topic_names(problem)
    assert three_d['topics'] == {f'/{topics["markers"]}': {'visible': True}}
    drawn = PendulumMarkers(problem).state(problem.initial_state, 0, problem.default_delta)
    frames = {m.header.frame_id for m in drawn.markers} if drawn is not None else set()
    assert frames <= {three_d['followTf']} and three_d['layers']['grid']['frameId'] == \
        three_d['followTf']


def test_the_layout_files_are_valid_json_one_per_problem():
    assert sorted(p.stem for p in LAYOUT_DIR.glob('*.json')) == sorted(problem_names())
    for path in LAYOUT_DIR.glob('*.json'):
        json.loads(path.read_text(encoding='utf-8'))
