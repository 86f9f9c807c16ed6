"""`sapga launch` as a ROS user expects it: --help at every level, `sapga --version`, a
namespace, remaps and --ros-args for every node, and no AMENT_PREFIX_PATH needed
(sapga_ros/launch/ros_args.py, sapga_ros/launch/prefix.py)."""
from __future__ import annotations

import argparse
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from domains import ros_domain
from process_helpers import sapga_in_process
from ros_helpers import executable
from sapga_ros import package_version, version_of_package_xml
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.launch.prefix import MARKER, ensure_ament_prefix, own_prefixes
from sapga_ros.launch.ros_args import RosOptions, namespace, remap, split_ros_args
from sim_nodes.problem import load_problem
from test_launch import launch, recorded_episodes, sapga_eval_json, the_bag

REPO = Path(__file__).resolve().parents[1]


def sapga(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([str(executable('sapga')), *args], capture_output=True, text=True,
                          timeout=120, env=env)


def test_sapga_version_is_the_package_xml_version():
    """`sapga --version` and sapga_ros.__version__ both say package.xml's <version>."""
    import sapga_ros
    expected = version_of_package_xml(REPO / 'package.xml')
    assert expected and sapga_ros.__version__ == package_version() == expected
    done = sapga('--version')
    assert done.returncode == 0 and done.stdout.strip() == f'sapga {expected}'


@pytest.mark.parametrize('args, words', [
    (['launch', '--help'], ['usage: sapga launch NAME', 'swingup', 'train_deploy']),
    (['launch', '-h'], ['usage: sapga launch NAME']),
    (['launch', 'swingup', '--help'], ['usage: sapga launch swingup', '--namespace NS',
                                       '--remap FROM:=TO', '--ros-args']),
    (['launch', 'train_deploy', '--help'], ['usage: sapga launch train_deploy',
                                            '--namespace NS']),
])
def test_launch_help_prints_usage_and_exits_0(args, words):
    """`sapga launch --help` and each launch's --help print their usage and exit 0 (the
    first through the executable, the others calling its main in process)."""
    done = sapga(*args) if args == ['launch', '--help'] else sapga_in_process(args)
    assert done.returncode == 0, done.stderr
    assert all(w in done.stdout for w in words), done.stdout


def test_launch_without_a_name_is_a_usage_error():
    """`sapga launch` alone says a NAME is needed, exit 2."""
    done = sapga_in_process(['launch'])
    assert done.returncode == 2 and 'a launch NAME is required' in done.stderr


def test_ros_options_become_the_same_ros_arguments_for_every_node(tmp_path):
    """--namespace, --remap and the --ros-args tail become -r rules and arguments of each
    node, and of the launch's own node (namespace and remaps only)."""
    own, tail = split_ros_args(['--out', 'x', '--ros-args', '--log-level', 'debug'])
    assert own == ['--out', 'x'] and tail == ['--log-level', 'debug']
    options = RosOptions.of(argparse.Namespace(namespace='/robot1', remap=['a:=b'],
                                               ros_args=tail))
    path = tmp_path / 'p.yaml'
    assert options.node_args(path) == ['--ros-args', '--params-file', str(path), '-r',
                                       '__ns:=/robot1', '-r', 'a:=b', '--log-level', 'debug']
    assert options.launch_node_args() == ['--ros-args', '-r', '__ns:=/robot1', '-r', 'a:=b']
    assert RosOptions.of(argparse.Namespace()).node_args(path) == [
        '--ros-args', '--params-file', str(path)]


@pytest.mark.parametrize('text', ['', '/', '1robot', 'a b', 'robot/../x', 'ro-bot'])
def test_bad_namespaces_are_refused(text):
    """A namespace that is not ROS names separated by / is an argument error."""
    with pytest.raises(argparse.ArgumentTypeError):
        namespace(text)


@pytest.mark.parametrize('text', ['a', 'a:=', ':=b', '__node:=x', '__ns:=/x', 'a b:=c'])
def test_bad_remaps_are_refused(text):
    """A remap that is not FROM:=TO of names, or renames the launch's nodes, is refused."""
    with pytest.raises(argparse.ArgumentTypeError):
        remap(text)


def test_namespace_and_remaps_are_given_as_ros_users_write_them():
    """'robot1' and '/robot1/' are the namespace /robot1; '~/x:=/y' is a remap."""
    assert namespace('robot1') == namespace('/robot1/') == '/robot1'
    assert remap('~/x:=/y') == '~/x:=/y'


def test_this_install_is_found_as_an_ament_prefix_when_none_is_set():
    """With AMENT_PREFIX_PATH unset, sapga puts its own install prefix there."""
    prefixes = own_prefixes()
    assert prefixes and (Path(prefixes[0]) / MARKER / 'sapga_ros').is_file()
    env: dict[str, str] = {}
    assert ensure_ament_prefix(env) == prefixes and env['AMENT_PREFIX_PATH'].split(
        os.pathsep) == prefixes
    env = {'AMENT_PREFIX_PATH': prefixes[0]}
    assert ensure_ament_prefix(env) == [] and env['AMENT_PREFIX_PATH'] == prefixes[0]


@pytest.fixture(scope='module')
def small_policy(tmp_path_factory) -> Path:
    problem = load_problem('acrobot')
    rng = np.random.default_rng(11)
    path = tmp_path_factory.mktemp('policy') / 'small.json'
    ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (60, 4)),
                   rng.integers(0, 3, 60), meta={'delta': 0.3}).save(path)
    return path


def test_a_namespaced_swingup_lives_under_the_namespace_with_remaps_and_ros_args(
        tmp_path, small_policy, capsys):
    """`sapga launch swingup --namespace robot1 --remap reward:=reward_signal --ros-args
    --log-level warn` runs its lockstep episode under /robot1: the bag has
    /robot1/joint_states and /robot1/reward_signal, and the episode equals sapga eval."""
    done = launch(['swingup', '--policy', str(small_policy), '--out', 'rec', '--namespace',
                   'robot1', '--remap', 'reward:=reward_signal', '--ros-args', '--log-level',
                   'warn'], tmp_path)
    assert 'every lockstep episode is equal' in done.stdout
    assert '[INFO]' not in done.stdout              # --log-level warn reached every node
    bag = the_bag(tmp_path / 'rec')
    topics = {t['topic_metadata']['name'] for t in yaml.safe_load(
        (bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information'][
            'topics_with_message_count']}
    assert {'/robot1/joint_states', '/robot1/reward_signal', '/robot1/episode_event',
            '/robot1/command_stamped'} <= topics
    assert not any(t in topics for t in ('/joint_states', '/reward', '/robot1/reward'))
    expected = sapga_eval_json(small_policy, capsys)
    ends = end_events_under(bag, '/robot1')
    assert [(e['return'], e['step']) for e in ends] == [(expected['return'],
                                                         expected['steps'])]


def end_events_under(bag: Path, ns: str) -> list[dict]:
    """The episode end events of a bag whose topics are under namespace ``ns``."""
    import json
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    ends = []
    (path,) = bag.glob('*.mcap')
    with open(path, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(log_time_order=True):
            if channel.topic == f'{ns}/episode_event':
                event = json.loads(msg.data)
                if event['event'] in ('goal', 'step_limit'):
                    ends.append(event)
    return ends


def test_swingup_runs_without_ament_prefix_path_in_the_environment(tmp_path, small_policy):
    """With AMENT_PREFIX_PATH removed from the environment, `sapga launch swingup` finds its
    own install and its lockstep episode is recorded as usual."""
    env = {k: v for k, v in os.environ.items() if k != 'AMENT_PREFIX_PATH'}
    with ros_domain() as domain:
        env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                   PYTHONUNBUFFERED='1')
        done = subprocess.run([str(executable('sapga')), 'launch', 'swingup', '--policy',
                               str(small_policy), '--out', 'rec'], env=env, cwd=tmp_path,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              timeout=150)
    assert done.returncode == 0, done.stdout[-4000:]
    assert 'every lockstep episode is equal' in done.stdout
    ends, _ = recorded_episodes(the_bag(tmp_path / 'rec'))
    assert len(ends) == 1


def test_a_lockstep_reference_honours_or_declines_the_ros_args(small_policy, capsys):
    """Only the settings the offline evaluation takes are honoured; any other, or a
    parameters file, leaves the launch without a reference (it says why), and a launch
    report names the episodes that differ."""
    from sapga_ros.launch.reference import lockstep_reference, parameter_overrides
    from sapga_ros.launch.supervisor import Supervisor
    from sapga_ros.launch.swingup import SwingupResult, print_swingup
    from sapga_ros.policies.runnable import load_policy
    assert parameter_overrides(('--log-level', 'warn', '-p', 'delay:=1', '--param',
                                'disturbance:=field', '-p', 'replan_fit:=0.05')) == {
        'delay': 1, 'disturbance': 'field', 'replan_fit': 0.05}
    policy = load_policy(small_policy)
    for extra, why in ((('-p', 'n_step:=50'), '--ros-args set n_step'),
                       (('--params-file', 'p.yaml'), 'a parameters file'),
                       (('-p', 'disturbance_seed:=abc'), 'do not evaluate offline'),
                       (('-p', 'disturbance:=gust'), "unknown disturbance 'gust'")):
        ref = lockstep_reference(policy, 0.3, None, 2, False, extra)
        assert ref.episodes is None and why in ref.why
    plain = lockstep_reference(policy, 0.3, None, 2, False, ('-p', 'markers:=false'))
    assert plain.by == 'sapga eval' and len(plain.episodes) == 1
    from sapga_ros.evaluation.replan import ReplanSettings, replanned_episode
    planned = lockstep_reference(policy, 0.3, None, 2, False, (
        '-p', 'replan:=true', '-p', 'replan_rounds:=2', '-p', 'replan_fit:=0.05'))
    assert planned.by == 'sapga eval --replan --replan-fit 0.05 --replan-rounds 2'
    assert planned.episodes == [replanned_episode(policy, 0.3, settings=ReplanSettings(
        replan_rounds=2, replan_fit=0.05))]
    end = {'event': 'step_limit', 'episode': 1, 'step': 400, 'return': -1000.0,
           'delta_star': 0.5}
    result = SwingupResult([end, {**end, 'episode': 2}], [],
                           {**plain.episodes[0], 'by': 'sapga eval'}, False, different=(2,))
    assert print_swingup(Supervisor(), result) == 1
    assert 'DIFFERENT from lockstep episode(s) 2' in capsys.readouterr().out
