"""Launch (sapga_ros/launch): the process supervisor (prefixed output, a crashed child ends
the launch, Ctrl-C stops every child) and the swingup / train_deploy launches end to end over
real nodes, whose lockstep episodes equal the offline evaluation."""
from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from domains import ros_domain
from ros_helpers import executable
from sapga_ros.cli import main as cli
from sapga_ros.errors import SapgaError
from sapga_ros.io.outputs import check_output_dir
from sapga_ros.launch import run_launch
from sapga_ros.launch.supervisor import ChildExited, Supervisor, exit_code
from sapga_ros.policies.exemplar import ExemplarPolicy
from sim_nodes.problem import load_problem

LAUNCH_TIMEOUT_S = 150  # [s] bound on a whole launch: a failing test, not a timing check


def python_child(code: str) -> list[str]:
    return [sys.executable, '-c', textwrap.dedent(code)]


def test_output_lines_carry_the_child_name():
    """Every line a child writes, stdout or stderr, reaches the launch prefixed with its name."""
    stream = io.StringIO()
    with Supervisor(stream=stream) as sup:
        sup.start('alpha', python_child('print("hello"); print("second line")'))
        sup.start('beta', python_child('import sys; sys.stderr.write("oops\\n")'))
        sup.wait()
    lines = stream.getvalue().splitlines()
    assert '[alpha] hello' in lines and '[alpha] second line' in lines
    assert '[beta] oops' in lines


def test_a_crashed_child_ends_the_launch_with_its_name_and_exit_code():
    """A child that exits with an error stops the launch, naming it and its code; the rest stop."""
    stream = io.StringIO()
    sup = Supervisor(stream=stream, stop_timeout=5.0)
    with sup:
        sleeper = sup.start('sleeper', python_child('import time; time.sleep(120)'))
        sup.start('crasher', python_child('import time, sys; time.sleep(0.2); sys.exit(3)'))
        with pytest.raises(ChildExited) as info:
            sup.wait(lambda: False, what='forever')
    assert info.value.name == 'crasher' and info.value.returncode == 3
    assert 'crasher exited with code 3' in str(info.value)
    assert exit_code(info.value) == 1
    assert sleeper.returncode is not None        # stopped with the launch


SUPERVISED = '''
import sys
from sapga_ros.launch.supervisor import Interrupted, Supervisor, exit_code
polite = """
import signal, sys, time
def on_int(*a):
    open(sys.argv[1], 'w').write('SIGINT'); sys.exit(0)
signal.signal(signal.SIGINT, on_int)
print('ready', flush=True)
time.sleep(120)
"""
stubborn = """
import signal, sys, time
signal.signal(signal.SIGINT, signal.SIG_IGN)
def on_term(*a):
    open(sys.argv[1], 'w').write('SIGTERM'); sys.exit(0)
signal.signal(signal.SIGTERM, on_term)
print('ready', flush=True)
time.sleep(120)
"""
sup = Supervisor(stop_timeout=1.0)
try:
    with sup, sup.handle_signals():
        sup.start('polite', [sys.executable, '-c', polite, sys.argv[1]])
        sup.start('stubborn', [sys.executable, '-c', stubborn, sys.argv[2]])
        sup.wait(lambda: False, what='Ctrl-C')
except Interrupted as exc:
    print('interrupted', flush=True)
    sys.exit(exit_code(exc))
'''


def test_ctrl_c_stops_every_child_with_sigint_then_sigterm(tmp_path):
    """Ctrl-C to the launcher sends SIGINT to every child, SIGTERM to one that ignores it."""
    polite, stubborn = tmp_path / 'polite', tmp_path / 'stubborn'
    proc = subprocess.Popen([sys.executable, '-c', SUPERVISED, str(polite), str(stubborn)],
                            stdout=subprocess.PIPE, text=True)
    ready = 0
    for line in proc.stdout:
        ready += line.endswith('ready\n')
        if ready == 2:
            break
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGINT
    assert 'interrupted' in out and '[launch] stubborn still running: SIGTERM' in out
    assert polite.read_text() == 'SIGINT' and stubborn.read_text() == 'SIGTERM'


def test_unknown_launches_and_bad_policy_files_are_refused_before_any_node_starts(
        tmp_path, capsys):
    """An unknown launch name or a bad policy file gives exit code 2 and says what is wrong."""
    assert run_launch('nope', []) == 2
    assert "unknown launch 'nope'" in capsys.readouterr().err
    (tmp_path / 'bad.json').write_text('{"format": "sapga-policy/1"')
    assert run_launch('swingup', ['--policy', str(tmp_path / 'bad.json'),
                                  '--out', str(tmp_path / 'rec')]) == 2
    assert 'bad.json: malformed JSON' in capsys.readouterr().out
    assert not (tmp_path / 'rec').exists()


def test_outputs_that_are_not_directories_are_refused_before_any_node_starts(
        tmp_path, capsys):
    """``--out`` a device, a file, a FIFO or a path through a file: one line naming it, exit
    2, for both launches that record, and nothing is made."""
    problem = load_problem('acrobot')
    rng = np.random.default_rng(3)
    ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (10, 4)),
                   rng.integers(0, 3, 10)).save(tmp_path / 'p.json')
    (tmp_path / 'file').write_text('x')
    os.mkfifo(tmp_path / 'fifo')
    for out, said in (('/dev/null', 'exists and is not a directory'),
                      (tmp_path / 'file', 'exists and is not a directory'),
                      (tmp_path / 'fifo', 'exists and is not a directory'),
                      (tmp_path / 'file' / 'x', 'is not a folder'),
                      (tmp_path / 'file' / 'x' / 'y', 'is not a folder')):
        for name, args in (('swingup', ['--policy', str(tmp_path / 'p.json')]),
                           ('train_deploy', ['--steps', '1000'])):
            assert run_launch(name, [*args, '--out', str(out)]) == 2
            got = capsys.readouterr()
            lines = [line for line in (got.out + got.err).splitlines()
                     if f'--out {out}' in line]
            assert len(lines) == 1 and said in lines[0] and 'Traceback' not in got.err
    assert (tmp_path / 'file').read_text() == 'x'
    # folders missing on the way are made (as before): the nearest existing one is checked
    check_output_dir(tmp_path / 'no' / 'x', '--out', parents=True)
    with pytest.raises(SapgaError, match='does not exist'):
        check_output_dir(tmp_path / 'no' / 'x', '--out')


# end to end over real nodes -------------------------------------------------------------

def launch(args: list[str], tmp_path: Path) -> subprocess.CompletedProcess:
    """Run ``sapga launch ...`` in a ROS domain of its own (tests/domains.py), beside the
    other workers' tests; fail with its output on error."""
    with ros_domain() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
        done = subprocess.run([str(executable('sapga')), 'launch', *args], env=env,
                              cwd=tmp_path, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, timeout=LAUNCH_TIMEOUT_S)
    assert done.returncode == 0, done.stdout[-4000:]
    return done


def the_bag(directory: Path) -> Path:
    """The one bag directory a launch wrote into ``directory``."""
    (bag,) = [p for p in directory.iterdir() if (p / 'metadata.yaml').is_file()]
    return bag


def recorded_episodes(bag: Path) -> tuple[list[dict], list[float]]:
    """The episode end events and the rewards of a bag, read with the mcap library."""
    ends, rewards = [], []
    (path,) = bag.glob('*.mcap')
    with open(path, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        for _, channel, _, msg in reader.iter_decoded_messages(log_time_order=True):
            if channel.topic == '/episode_event':
                event = json.loads(msg.data)
                if event['event'] in ('goal', 'step_limit'):
                    ends.append(event)
            elif channel.topic == '/reward':
                rewards.append(msg.data)
    return ends, rewards


def sapga_eval_json(path: Path, capsys, *extra: str) -> dict:
    assert cli.main(['eval', str(path), '--json', *extra]) == 0
    return json.loads(capsys.readouterr().out)


def test_swingup_lockstep_recording_equals_sapga_eval(tmp_path, capsys):
    """Each lockstep episode of the swingup launch, as recorded in the bag, equals sapga eval."""
    problem = load_problem('acrobot')
    rng = np.random.default_rng(11)
    policy = ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (60, 4)),
                            rng.integers(0, 3, 60), meta={'delta': 0.3})
    policy.save(tmp_path / 'small.json')
    done = launch(['swingup', '--policy', 'small.json', '--out', 'rec', '--episodes', '2'],
                  tmp_path)
    assert '[sim] ' in done.stdout and '[recorder] ' in done.stdout
    assert 'every lockstep episode is equal' in done.stdout
    recording = the_bag(tmp_path / 'rec')
    ends, rewards = recorded_episodes(recording)
    expected = sapga_eval_json(tmp_path / 'small.json', capsys)   # delta from meta: 0.3
    assert len(ends) == 2
    for event in ends:
        assert event['return'] == expected['return'] and event['step'] == expected['steps']
        assert event['delta_star'] == expected['delta_star']
        assert event['goal_delta'] == 0.3
    assert rewards and all(-5.0 <= r <= -1.0 for r in rewards)   # the acrobot's reward range


def test_swingup_replan_plays_sapga_eval_replan(tmp_path, capsys):
    """``--replan``: the policy node re-plans, and each lockstep episode in the bag equals
    ``sapga eval --replan``; settings it cannot take are refused before any node starts."""
    problem = load_problem('acrobot')
    rng = np.random.default_rng(12)
    policy = ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (40, 4)),
                            rng.integers(0, 3, 40), meta={'delta': 0.3})
    policy.save(tmp_path / 'small.json')
    done = launch(['swingup', '--policy', 'small.json', '--out', 'rec', '--replan'], tmp_path)
    assert 'offline evaluation (sapga eval --replan)' in done.stdout
    assert 'every lockstep episode is equal' in done.stdout
    (end,), _ = recorded_episodes(the_bag(tmp_path / 'rec'))
    planned = sapga_eval_json(tmp_path / 'small.json', capsys, '--replan')
    plain = sapga_eval_json(tmp_path / 'small.json', capsys)
    assert end['return'] == planned['return']['max'] != plain['return']
    assert end['delta_star'] == planned['delta_star']['max']
    assert run_launch('swingup', ['--policy', str(tmp_path / 'small.json'), '--out',
                                  str(tmp_path / 'h'), '--replan', '--n-step', '800']) == 2
    said = capsys.readouterr()
    assert 'no --delta or --n-step with it' in said.out + said.err
    assert not (tmp_path / 'h').exists()


def test_swingup_compares_disturbed_lockstep_episodes_with_their_own_draws(tmp_path):
    """``--ros-args -p disturbance:=field -p disturbance_seed:=3 -p delay:=1``: the launch
    compares each lockstep episode with the evaluation's episode of the same draws (it
    said DIFFERENT before, against the undisturbed episode), and the bag's episodes are
    those episodes."""
    from sapga_ros.evaluation.evaluator import Evaluator
    from sapga_ros.policies.classical import ahead
    from sim_nodes.disturbance import load_disturbance
    from sim_nodes.draws import HELD_OUT
    problem = load_problem('acrobot')
    rng = np.random.default_rng(13)
    near = problem.initial_state + rng.uniform(-1, 1, (40, 4)) * [0.3, 0.3, 2.0, 2.0]
    policy = ExemplarPolicy(problem, near, rng.integers(0, 3, 40), meta={'delta': 0.3})
    policy.save(tmp_path / 'small.json')     # exemplars about its swing: its actions vary
    done = launch(['swingup', '--policy', 'small.json', '--out', 'rec', '--episodes', '2',
                   '--ros-args', '-p', 'disturbance:=field', '-p', 'disturbance_seed:=3',
                   '-p', 'delay:=1', '-p', 'executor:=events'], tmp_path)
    assert ('offline evaluation (sapga eval --disturbance field --seed 3 --delay 1, each '
            'episode on its own draws): every lockstep episode is equal') in done.stdout
    ends, _ = recorded_episodes(the_bag(tmp_path / 'rec'))
    ev = Evaluator(problem, 0.3, disturbance=load_disturbance('field'))
    eps = [ev.episode(ahead(policy, 1), (3, 0, HELD_OUT, e)) for e in range(2)]
    assert [(e['step'], e['return'], e['delta_star']) for e in ends] == [
        (ep.steps, ep.ret, ep.delta_star) for ep in eps]
    assert eps[0].ret != eps[1].ret != ev.episode(policy, (3, 0, HELD_OUT, 1)).ret  # the
    # draws and the delay both matter


def test_swingup_deploys_a_mountain_car_policy_like_the_pendulums(tmp_path, capsys):
    """A mountain-car policy runs through ``mountain_car_sim``: the recorded episode reaches
    the goal and equals sapga eval."""
    problem = load_problem('mountain_car')
    pump = ExemplarPolicy(problem, np.array([[-0.5, 0.01], [-0.5, -0.01]]), np.array([1, 0]))
    pump.save(tmp_path / 'pump.json')   # push the way the car moves: pumps energy in
    done = launch(['swingup', '--policy', 'pump.json', '--mode', 'lockstep', '--episodes', '1',
                   '--out', 'rec'], tmp_path)
    assert '[mountain_car_sim]' in done.stdout
    assert 'every lockstep episode is equal' in done.stdout
    (end,), rewards = recorded_episodes(the_bag(tmp_path / 'rec'))
    expected = sapga_eval_json(tmp_path / 'pump.json', capsys)
    assert expected['reached'] and end['event'] == 'goal'
    assert (end['return'], end['step']) == (expected['return'], expected['steps'])
    assert rewards == [-1.0] * expected['steps']


def test_train_deploy_serves_records_and_equals_the_offline_evaluation(tmp_path, capsys):
    """train_deploy's trained, served, recorded episode equals sapga eval of the policy file."""
    done = launch(['train_deploy', '--steps', '100000', '--delta', '0.3', '--out', 'td',
                   '--jobs', '1'], tmp_path)
    assert '[trainer] ' in done.stdout and '[policy] ' in done.stdout
    assert 'ROS episode == offline evaluation: yes' in done.stdout
    recording = the_bag(tmp_path / 'td')
    (end,), _ = recorded_episodes(recording)
    expected = sapga_eval_json(tmp_path / 'td' / 'policy.json', capsys)
    assert (end['return'], end['step']) == (expected['return'], expected['steps'])
    assert (tmp_path / 'td' / 'checkpoint').is_dir()


def test_swingup_runs_the_classical_controller_on_the_hold_task(tmp_path, capsys):
    """The classical policy file of acrobot_hold deployed by the swingup launch: the lockstep
    episode runs all 1000 steps (no goal end), holds, and equals sapga eval, hold measures
    included."""
    assert cli.main(['classical', '--problem', 'acrobot_hold', '--out',
                     str(tmp_path / 'c.json')]) == 0
    end, rewards = lockstep_hold_equals_eval('c.json', tmp_path, capsys)
    assert end['event'] == 'step_limit' and end['step'] == 1000
    assert len(rewards) == 1000
    assert end['hold_fraction'] >= 0.95


def lockstep_hold_equals_eval(policy: str, tmp_path, capsys,
                              n_step: int | None = None) -> tuple[dict, list]:
    """Deploy ``policy`` (in tmp_path) with a lockstep swingup launch of one episode
    (``--n-step``: that long); its recorded end event equals sapga eval (``--max-steps``),
    hold measures included; (end event, rewards)."""
    capsys.readouterr()
    length = [] if n_step is None else ['--n-step', str(n_step)]
    done = launch(['swingup', '--policy', policy, '--mode', 'lockstep', '--episodes', '1',
                   '--out', 'rec', *length], tmp_path)
    assert 'every lockstep episode is equal' in done.stdout
    (end,), rewards = recorded_episodes(the_bag(tmp_path / 'rec'))
    expected = sapga_eval_json(tmp_path / policy, capsys,
                               *(['--max-steps', str(n_step)] if n_step else []))
    assert n_step is None or end['step'] == n_step
    for key in ('return', 'steps', 'first_entry_step', 'hold_fraction', 'rail_contacts'):
        assert end['step' if key == 'steps' else key] == expected[key], key
    return end, rewards


def test_swingup_runs_a_hybrid_policy_like_sapga_eval(tmp_path, capsys):
    """An exemplar policy with an LQR catch (sapga train --catch lqr) through the policy
    node: the lockstep hold episode, run 1,200 steps (60 s) with --n-step, equals sapga eval
    --max-steps 1200, hold measures included."""
    assert cli.main(['train', '--problem', 'acrobot_hold', '--steps', '300000', '--seed', '1',
                     '--catch', 'lqr', '--quiet', '--out', str(tmp_path / 'h.json')]) == 0
    lockstep_hold_equals_eval('h.json', tmp_path, capsys, n_step=1200)


def realtime_states(bag: Path, pr) -> tuple[list[float], list[bool]]:
    """Receive times and 'in S_delta' of each distinct state of ``bag`` (read back with
    rosbags; the first state, re-published until answered, once), computed here from the
    states and the acrobot's goal box."""
    from rosbags.highlevel import AnyReader
    times, inside, stamps = [], [], set()
    with AnyReader([bag]) as reader:
        wanted = [c for c in reader.connections if c.topic == '/joint_states']
        for connection, t, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, connection.msgtype)
            stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
            if stamp in stamps:
                continue
            stamps.add(stamp)
            s = np.array([*msg.position, *msg.velocity])
            wrap = lambda d: abs((d + np.pi) % (2 * np.pi) - np.pi)  # noqa: E731
            box = 2 * np.pi * pr.default_delta
            inside.append(wrap(s[0] - np.pi / 2) <= box and wrap(s[1]) <= box
                          and abs(s[2]) <= 8 * np.pi * pr.default_delta
                          and abs(s[3]) <= 18 * np.pi * pr.default_delta)
            times.append(t * 1e-9)
    return times, inside


def realtime_hold(tmp_path: Path, policy: str, steps: int, factor: float, span: float) -> None:
    """A realtime swingup launch of ``policy`` for one episode of ``steps`` steps at
    real-time factor ``factor``: the bag has every state, the hold fraction after the first
    entry is >= 0.95, and the states span at least ``span`` of the episode's wall time."""
    launch(['swingup', '--policy', policy, '--mode', 'realtime', '--episodes', '1',
            '--n-step', str(steps), '--real-time-factor', str(factor), '--out', 'rec'],
           tmp_path)
    pr = load_problem('acrobot_hold')
    times, inside = realtime_states(the_bag(tmp_path / 'rec'), pr)
    assert len(times) == steps + 1                  # the initial state and every step
    first = inside.index(True)
    assert sum(inside[first:]) / len(inside[first:]) >= 0.95
    assert times[-1] - times[0] >= span * steps * pr.dt * pr.substeps / factor


@pytest.mark.long
def test_a_realtime_minute_of_the_hybrid_holds(tmp_path, capsys):
    """The hybrid (exemplars + LQR catch, `sapga train --problem acrobot_hold --catch lqr
    --steps 3000000 --seed 0`) deployed for a minute of sim time in real time (1,200 steps
    at 20 Hz, real-time factor 1): the bag, read back with rosbags, has every state, holds
    with hold fraction >= 0.95 after its first entry, and spans most of the minute: no
    step was taken in lockstep (a lockstep start once ran ~780 steps back to back).  At 10x
    real time on a loaded machine late commands change the trajectory (the zero-order hold
    on the last command is part of a realtime run), so this runs at 1x."""
    assert cli.main(['train', '--problem', 'acrobot_hold', '--steps', '3000000', '--seed', '0',
                     '--catch', 'lqr', '--quiet', '--out', str(tmp_path / 'h.json')]) == 0
    capsys.readouterr()
    realtime_hold(tmp_path, 'h.json', 1200, 1.0, 0.9)
