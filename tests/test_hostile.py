"""Hostile and mistaken input found in review: refused with one clear line, nothing lost."""
import json
import math
import signal
import subprocess
import sys
import numpy as np
import pytest

from sapga_ros.errors import CheckpointError, PolicyFileError
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.runnable import policy_from_json
from sapga_ros.recording.events import parse_event
from sapga_ros.optim.sapga import SapgaParams
from sapga_ros.optim.population import pack, unpack
from sapga_ros.training.loop import TrainConfig, train_sapga
from sim_nodes.problem import load_problem
from sim_nodes.ros.sim_node import check_setting

SAPGA = [sys.executable, '-m', 'sapga_ros.cli.main']


def _doc(problem):
    pol = ExemplarPolicy(problem, problem.initial_state[None, :], [0])
    return json.loads(pol.to_json())


def test_huge_integer_literal_is_a_policy_error_not_a_crash():
    """A 400-digit number in a policy file is refused naming the field (float overflow)."""
    pr = load_problem('acrobot')
    text = json.dumps(_doc(pr)).replace('"action": -2.0', '"action": ' + '9' * 400)
    with pytest.raises(PolicyFileError, match=r'exemplars\[0\].action: number too large'):
        policy_from_json(text)


def test_non_finite_meta_is_saved_as_null_and_loads_back():
    """A policy whose provenance holds inf (a goal never approached) still saves as JSON."""
    pr = load_problem('pdip')
    pol = ExemplarPolicy(pr, pr.initial_state[None, :], [1], meta={'delta_star': math.inf})
    back = policy_from_json(pol.to_json())
    assert back.meta == {'delta_star': None}


def test_malformed_event_text_is_not_an_event():
    """The recorder's event parser returns None for deeply nested or broken JSON."""
    assert parse_event('[' * 100_000) is None
    assert parse_event('{"event": ') is None
    assert parse_event('{"event": "goal"}') == {'event': 'goal'}


@pytest.mark.parametrize('name, value', [('real_time_factor', 1e-12),
                                         ('real_time_factor', 1e9),
                                         ('republish_period', 1e10)])
def test_sim_timer_settings_outside_a_sane_range_are_refused(name, value):
    """Periods that rclpy timers cannot represent are refused with the reason."""
    assert name in check_setting(name, value)


def test_damaged_checkpoint_population_is_refused():
    """Action indices out of range or non-finite states in a checkpoint are refused."""
    pr = load_problem('acrobot')
    rng = np.random.default_rng(0)
    from sapga_ros.optim.population import Individual
    pop = [Individual(ExemplarPolicy(pr, rng.uniform(pr.low, pr.high, (5, 4)), [0, 1, 2, 0, 1]))]
    arrays = pack(pop, 'pop')
    arrays['pop_actions'][0] = 7
    with pytest.raises(CheckpointError, match='out of range'):
        unpack(pr, arrays, 'pop')
    arrays = pack(pop, 'pop')
    arrays['pop_states'][1, 2] = np.nan
    with pytest.raises(CheckpointError, match='non-finite'):
        unpack(pr, arrays, 'pop')


def test_unwritable_outputs_are_refused_before_training(tmp_path):
    """``--out`` naming a directory is refused at once, before any step is simulated."""
    r = subprocess.run([*SAPGA, 'train', '--problem', 'acrobot', '--out', str(tmp_path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and 'is a directory' in r.stderr and 'Traceback' not in r.stderr
    r = subprocess.run([*SAPGA, 'eval', str(tmp_path)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and 'a directory, not a regular file' in r.stderr
    assert 'Traceback' not in r.stderr


def test_ctrl_c_during_training_saves_the_best_so_far(tmp_path):
    """Ctrl-C ends the run after its current generation and still writes the best policy and
    the log; the exit status is 130."""
    out = tmp_path / 'p.json'
    proc = subprocess.Popen([*SAPGA, 'train', '--problem', 'acrobot', '--steps', '100000000',
                             '--out', str(out), '--pop', '20', '--children', '4'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stderr.readline()        # the first progress line: training is under way
    assert first.startswith('steps'), first + proc.stderr.read()
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    doc = json.loads(out.read_text())
    assert 0 < doc['meta']['steps'] < 100_000_000
    assert out.with_suffix('.log.csv').is_file()


def test_small_params_train_with_nan_free_meta():
    """A tiny run's policy document has only finite numbers or nulls in its meta."""
    r = train_sapga(TrainConfig(problem='pdip', steps=20_000, seed=1,
                                params=SapgaParams(n_pop=4, n_child=2, l_min=3, l_max=6)))
    doc = json.loads(r.policy.to_json(), parse_constant=lambda name: pytest.fail(name))
    assert doc['meta']['steps'] >= 20_000
