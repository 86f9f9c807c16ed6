"""Trainer node (sapga_ros/nodes/trainer_node.py) over real Fast DDS: the best policy served on
get_policy during and after training, the hand-off to the policy node, the train and stop
services, /diagnostics, Q-learning runs, parameters, failed runs and a clean stop."""
from __future__ import annotations

import json
import math
import re
import threading

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from ros_helpers import Probe, isolated_ros
from sapga_ros.errors import ConfigError
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.nodes.policy_node import PolicyNode
from sapga_ros.nodes.trainer_node import TrainerNode
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.runnable import load_policy, policy_from_json
from sapga_ros.optim.sapga import SapgaParams
from sapga_ros.training.loop import TrainConfig, train_sapga
from sim_nodes.problem import load_problem

# A tiny run: a few generations of a small population, on one thread.
SMALL = {'n_pop': 10, 'n_child': 4, 'l_min': 10, 'l_max': 20, 'jobs': 1, 'delta': 0.3,
         'seed': 3}
BUDGET = 200_000


@pytest.fixture
def ros(monkeypatch, tmp_path):
    """An isolated ROS 2 domain with an executor thread (tests/ros_helpers.py)."""
    yield from isolated_ros(monkeypatch, tmp_path)


class Client(Node):
    """The trainer's services and /diagnostics, as any other node sees them."""

    def __init__(self, **kwargs) -> None:
        super().__init__('trainer_client', **kwargs)
        self.get_policy = self.create_client(Trigger, 'trainer_node/get_policy')
        self.train = self.create_client(Trigger, 'trainer_node/train')
        self.stop = self.create_client(Trigger, 'trainer_node/stop')
        self.lock = threading.Lock()
        self.diagnostics: list[dict[str, str]] = []
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 100)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith(': training'):
                values = {kv.key: kv.value for kv in status.values}
                values.update(message=status.message, level=int.from_bytes(status.level, 'big'))
                with self.lock:
                    self.diagnostics.append(values)

    def last(self) -> dict[str, str] | None:
        with self.lock:
            return self.diagnostics[-1] if self.diagnostics else None

    def states(self) -> list[str]:
        with self.lock:
            return [d['state'] for d in self.diagnostics]


def state_is(client: Client, state: str):
    return lambda: (client.last() or {}).get('state') == state


def stop_node(ros, node: TrainerNode) -> None:
    """Destroy ``node`` the way a Ctrl-C does (the harness must not destroy it again)."""
    ros.executor.remove_node(node)
    ros.nodes.remove(node)
    node.destroy_node()


def test_best_policy_is_served_during_training_and_a_second_train_is_refused(ros, tmp_path):
    """While a run goes on, get_policy serves its best evaluated policy and train refuses."""
    out = tmp_path / 'best.json'
    client = ros.start(Client)
    trainer = ros.start(TrainerNode, params={**SMALL, 'steps': 10**12, 'out': str(out),
                                             'train_on_start': True})
    response = ros.wait_for(lambda: (r := ros.call(client.get_policy, Trigger.Request()))
                            .success and r, 'a best policy during training')
    assert trainer.training
    policy = policy_from_json(response.message, 'acrobot')
    episode = Evaluator(policy.problem, SMALL['delta']).episode(policy)
    assert episode.ret == policy.meta['value']              # served = evaluated, with meta
    assert episode.delta_star == policy.meta['delta_star']

    refused = ros.call(client.train, Trigger.Request())
    assert not refused.success and 'already training' in refused.message
    assert trainer.training

    stop_node(ros, trainer)                                  # what Ctrl-C does
    assert not trainer.training
    saved = load_policy(out, 'acrobot')                      # the best so far is on disk
    assert saved.meta['value'] >= policy.meta['value']
    assert saved.meta['steps'] < 10**12


def test_trained_policy_reaches_the_policy_node_over_load_policy(ros, tmp_path):
    """The real trainer executable's best policy is what the policy node loads over the service."""
    out = tmp_path / 'policy.json'
    params = {**SMALL, 'steps': BUDGET, 'out': str(out), 'train_on_start': 'true'}
    ros.spawn('trainer_node', '--ros-args',
              *[a for k, v in params.items() for a in ('-p', f'{k}:={v}')])
    client = ros.start(Client)
    probe = ros.start(Probe, problem=load_problem('acrobot'))
    policy_node = ros.start(PolicyNode)
    ros.wait_for(state_is(client, 'done'), 'the trainer to finish', timeout=90)

    served = ros.call(client.get_policy, Trigger.Request())
    assert served.success and served.message == out.read_text(encoding='utf-8')
    response = ros.call(probe.load_policy, Trigger.Request())
    assert response.success, response.message
    loaded, written = policy_node.active.policy, load_policy(out, 'acrobot')
    assert np.array_equal(loaded.states, written.states)
    assert np.array_equal(loaded.actions, written.actions)
    assert loaded.meta == written.meta and written.meta['steps'] >= BUDGET


def test_diagnostics_report_the_state_and_progress_of_a_run(ros, tmp_path):
    """/diagnostics goes idle -> training -> done with steps, best value and delta* as logged."""
    client = ros.start(Client)
    trainer = ros.start(TrainerNode, params={**SMALL, 'steps': BUDGET,
                                             'diagnostics_period': 0.2})
    ros.wait_for(state_is(client, 'idle'), 'idle diagnostics')
    assert not ros.call(client.get_policy, Trigger.Request()).success
    started = ros.call(client.train, Trigger.Request())
    assert started.success and f'{BUDGET} steps' in started.message
    ros.wait_for(state_is(client, 'done'), 'the run to finish', timeout=60)
    states = client.states()
    assert states.index('idle') < states.index('training') < states.index('done')
    done = client.last()
    assert {'steps', 'best_value', 'delta_star', 'steps_per_s', 'generation', 'budget',
            'delta', 'achieved', 'method', 'seed'} <= set(done)
    row = trainer.history[-1]
    assert int(done['steps']) == row['steps'] >= BUDGET == int(done['budget'])
    assert float(done['best_value']) == row['best_value']
    assert float(done['delta_star']) == row['delta_star']
    assert int(done['generation']) == row['generation'] and done['level'] == 0
    assert float(done['delta']) == SMALL['delta'] and done['method'] == 'sapga'
    assert done['achieved'] == str(row['delta_star'] <= SMALL['delta']).lower()
    steps = [int(d['steps']) for d in client.diagnostics if d['state'] != 'idle']
    assert steps == sorted(steps)


def test_node_run_equals_the_offline_run_with_the_same_settings(ros, tmp_path):
    """The node trains exactly what train_sapga does with the same seed and parameters."""
    out = tmp_path / 'node.json'
    client = ros.start(Client)
    ros.start(TrainerNode, params={**SMALL, 'steps': BUDGET, 'out': str(out),
                                   'train_on_start': True})
    ros.wait_for(state_is(client, 'done'), 'the run to finish', timeout=60)
    config = TrainConfig(problem='acrobot', delta=SMALL['delta'], steps=BUDGET,
                         seed=SMALL['seed'], jobs=1,
                         params=SapgaParams(n_pop=10, n_child=4, l_min=10, l_max=20))
    offline = train_sapga(config).policy
    node = load_policy(out, 'acrobot')
    assert np.array_equal(node.states, offline.states)
    assert np.array_equal(node.actions, offline.actions)
    assert node.meta['value'] == offline.meta['value']
    assert (tmp_path / 'node.log.csv').read_text().count('\n') == node.meta['generations'] + 1


def test_policy_file_is_served_until_training_finds_a_best(ros, tmp_path):
    """get_policy serves policy_file until a run's first best policy replaces it."""
    problem = load_problem('acrobot')
    rng = np.random.default_rng(0)
    given = ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (30, 4)),
                           rng.integers(0, 3, 30), meta={'note': 'hand-written'})
    given.save(tmp_path / 'given.json')
    client = ros.start(Client)
    ros.start(TrainerNode, params={**SMALL, 'steps': BUDGET,
                                   'policy_file': str(tmp_path / 'given.json')})
    first = ros.call(client.get_policy, Trigger.Request())
    assert first.success and json.loads(first.message)['meta'] == {'note': 'hand-written'}
    assert ros.call(client.train, Trigger.Request()).success
    ros.wait_for(state_is(client, 'done'), 'the run to finish', timeout=60)
    trained = json.loads(ros.call(client.get_policy, Trigger.Request()).message)
    assert trained['meta']['method'] == 'sapga' and trained['meta']['steps'] >= BUDGET


def test_q_learning_runs_but_get_policy_says_a_q_table_is_not_served(ros, tmp_path):
    """A QL run writes its Q-table file; get_policy refuses, saying why, instead of serving."""
    out = tmp_path / 'q.json'
    client = ros.start(Client)
    ros.start(TrainerNode, params={'method': 'ql', 'steps': 20_000, 'out': str(out),
                                   'delta': 0.3, 'train_on_start': True})
    response = ros.call(client.get_policy, Trigger.Request())
    assert not response.success and 'Q-table' in response.message
    ros.wait_for(state_is(client, 'done'), 'the QL run to finish', timeout=60)
    response = ros.call(client.get_policy, Trigger.Request())
    assert not response.success and 'method ql' in response.message
    assert json.loads(out.read_text())['format'] == 'sapga-qtable/1'
    assert client.last()['method'] == 'ql' and int(client.last()['episodes']) > 0


def test_cmaes_runs_and_its_best_policy_is_served(ros, tmp_path):
    """A CMA-ES run (method cmaes, its strategy parameters as node parameters) writes its
    best state-action policy and serves the same policy on get_policy."""
    out = tmp_path / 'c.json'
    client = ros.start(Client)
    ros.start(TrainerNode, params={'method': 'cmaes', 'steps': 20_000, 'out': str(out),
                                   'exemplars': 8, 'popsize': 6, 'train_on_start': True})
    ros.wait_for(state_is(client, 'done'), 'the CMA-ES run to finish', timeout=60)
    response = ros.call(client.get_policy, Trigger.Request())
    assert response.success, response.message
    served, saved = json.loads(response.message), json.loads(out.read_text())
    assert served['meta']['method'] == 'cmaes' and served['meta']['steps'] >= 20_000
    assert served['meta']['trainer'] == {'exemplars': 8, 'sigma0': 0.3, 'popsize': 6}
    assert len(served['exemplars']) == 8 and served['exemplars'] == saved['exemplars']
    assert client.last()['method'] == 'cmaes'


def test_invalid_parameters_are_refused_with_the_reason(ros, tmp_path):
    """Bad settings (a policy file that cannot be served among them) fail at start or are
    refused with the reason; the node keeps serving."""
    with pytest.raises(ConfigError, match='method'):
        ros.start(TrainerNode, params={'method': 'ppo'})
    for delta in (math.nan, -1.0):          # no sentinel: only a delta the run can use
        with pytest.raises(ConfigError, match=rf'delta: expected a number in \[0, 1e9\], '
                                              rf'got {delta}'):
            ros.start(TrainerNode, params={'delta': delta}, node_name=f'bad_{delta != delta}')
    with pytest.raises(ConfigError, match=r'policy_file: .*missing\.json: cannot read'):
        ros.start(TrainerNode, params={'policy_file': str(tmp_path / 'missing.json')},
                  node_name='bad_file')
    trainer = ros.start(TrainerNode)
    client = ros.start(Client)
    response = ros.call(client.get_policy, Trigger.Request())
    assert not response.success and 'no policy yet' in response.message
    assert trainer.train_config().delta == load_problem('acrobot').default_delta
    for name, value in [('steps', 0), ('n_pop', 1), ('delta', math.inf), ('delta', -1.0),
                        ('jobs', -1), ('method', 'x'),
                        ('policy_file', str(tmp_path / 'missing.json'))]:
        result = trainer.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful and name in result.reason, (name, result.reason)
    assert trainer.set_parameters([Parameter('delta', value=0)])[0].successful  # int is fine
    assert trainer.set_parameters([Parameter('l_min', value=120)])[0].successful
    refused = ros.call(client.train, Trigger.Request())
    assert not refused.success and 'l_min 120 is larger than l_max 100' in refused.message
    assert trainer.status()['state'] == 'idle'


def test_an_unwritable_policy_file_fails_the_run_but_the_policy_is_still_served(ros, tmp_path):
    """When out cannot be written the run reports failed, naming it, and get_policy serves."""
    out = tmp_path / 'file'
    out.mkdir()                                    # a directory: os.replace cannot write it
    client = ros.start(Client)
    ros.start(TrainerNode, params={**SMALL, 'steps': BUDGET, 'out': str(out),
                                   'train_on_start': True})
    ros.wait_for(state_is(client, 'failed'), 'the run to fail', timeout=60)
    last = client.last()
    assert str(tmp_path / 'file') in last['message'] and last['level'] == 2
    served = ros.call(client.get_policy, Trigger.Request())
    assert served.success and json.loads(served.message)['meta']['steps'] >= BUDGET


def test_stop_ends_the_run_after_its_round_saves_and_reports_stopped(ros, tmp_path):
    """The stop service answers once the best policy, log and checkpoint are written, saying
    where; /diagnostics reports stopped; the checkpoint resumes; stop with no run is refused."""
    out = tmp_path / 'best.json'
    client = ros.start(Client)
    trainer = ros.start(TrainerNode, params={**SMALL, 'steps': 10**12, 'out': str(out),
                                             'train_on_start': True})
    ros.wait_for(lambda: len(trainer.history) >= 2, 'two generations')
    response = ros.call(client.stop, Trigger.Request())
    assert response.success, response.message
    assert response.message.startswith('stopped after')
    assert str(out) in response.message and str(tmp_path / 'best.ckpt') in response.message
    ros.wait_for(state_is(client, 'stopped'), '/diagnostics to report stopped')
    assert client.last()['checkpoint'] == str(tmp_path / 'best.ckpt')
    saved = load_policy(out, 'acrobot')
    assert saved.meta['steps'] == trainer.history[-1]['steps'] < 10**12
    assert (tmp_path / 'best.log.csv').read_text().count('\n') == len(trainer.history) + 1
    assert (tmp_path / 'best.ckpt' / 'checkpoint.npz').is_file()
    refused = ros.call(client.stop, Trigger.Request())
    assert not refused.success and 'no training run in progress' in refused.message
    resumed = trainer.set_parameters([Parameter('resume', value=True),
                                      Parameter('steps', value=saved.meta['steps'] + 1)])
    assert all(r.successful for r in resumed)
    assert ros.call(client.train, Trigger.Request()).success
    ros.wait_for(state_is(client, 'done'), 'the resumed run to finish', timeout=60)
    assert load_policy(out, 'acrobot').meta['steps'] > saved.meta['steps']


def test_a_failed_run_is_reported_and_the_next_run_works(ros, tmp_path, capfd):
    """A run that fails (a damaged checkpoint to resume) reports failed with one line, and a
    good run on the same node then trains, reports and logs its progress through the ROS
    logger (rclpy refuses a second severity from one call site: no crash, no fallback)."""
    ck = tmp_path / 'ck'
    ck.mkdir()
    (ck / 'checkpoint.npz').write_bytes(b'PK\x03\x04 not a checkpoint')
    client = ros.start(Client)
    trainer = ros.start(TrainerNode, params={**SMALL, 'steps': BUDGET, 'resume': True,
                                             'checkpoint': str(ck), 'log_period': 0.001,
                                             'diagnostics_period': 0.2})
    assert ros.call(client.train, Trigger.Request()).success
    ros.wait_for(state_is(client, 'failed'), 'the run to fail')
    failed = client.last()
    assert 'unreadable checkpoint' in failed['message'] and failed['level'] == 2
    assert '\n' not in failed['message']
    assert trainer.set_parameters([Parameter('resume', value=False)])[0].successful
    assert ros.call(client.train, Trigger.Request()).success
    ros.wait_for(state_is(client, 'done'), 'the second run to finish', timeout=60)
    states = client.states()
    assert states.index('failed') < len(states) - 1 - states[::-1].index('training')
    assert client.last()['level'] == 0 and int(client.last()['steps']) >= BUDGET
    # 'done' is published by the training thread just before it returns
    ros.wait_for(lambda: not trainer.training, 'the training thread to end')
    err = capfd.readouterr().err
    assert re.search(r'\[ERROR\] \[[\d.]+\] \[trainer_node\]: training failed: ', err), err
    assert re.search(r'\[INFO\] \[[\d.]+\] \[trainer_node\]: steps ', err), err
    assert 'Traceback' not in err


def test_out_in_a_missing_folder_is_refused_before_training(ros, tmp_path):
    """A run whose out (or checkpoint) folder does not exist is refused with the reason;
    no folder is created."""
    client = ros.start(Client)
    trainer = ros.start(TrainerNode, params={**SMALL, 'steps': BUDGET,
                                             'out': str(tmp_path / 'no' / 'p.json')})
    refused = ros.call(client.train, Trigger.Request())
    assert not refused.success and 'is not an existing folder' in refused.message
    assert trainer.set_parameters([Parameter('out', value=str(tmp_path / 'p.json')),
                                   Parameter('checkpoint', value=str(tmp_path / 'a' / 'b'))])
    refused = ros.call(client.train, Trigger.Request())
    assert not refused.success and 'checkpoint' in refused.message
    assert not (tmp_path / 'no').exists() and not (tmp_path / 'a').exists()


def test_sixty_mixed_train_and_stop_calls_are_all_answered(ros, tmp_path):
    """train / stop / get_policy spam on the trainer executable (as another process calls
    it): every request gets its answer, each consistent with what the node did, and the node
    goes on running."""
    from rclpy.qos import QoSProfile
    deep = QoSProfile(depth=100)            # this client keeps every response it gets
    proc = ros.spawn('trainer_node', '--ros-args', *[
        a for k, v in {**SMALL, 'steps': 10**12, 'out': str(tmp_path / 'best.json')}.items()
        for a in ('-p', f'{k}:={v}')])
    node = ros.start(lambda **kw: Node('spammer', **kw))
    clients = {name: node.create_client(Trigger, f'trainer_node/{name}', qos_profile=deep)
               for name in ('train', 'stop', 'get_policy')}
    for client in clients.values():
        ros.wait_for(client.service_is_ready, f'service {client.srv_name}', timeout=120)
    order = ['train', 'stop', 'train', 'get_policy', 'stop', 'stop', 'train', 'train'] * 8
    calls = [(name, clients[name].call_async(Trigger.Request())) for name in order[:60]]
    ros.wait_for(lambda: all(f.done() for _, f in calls),
                 f'answers to all {len(calls)} calls', timeout=300)
    for name, future in calls:
        r = future.result()
        if name == 'train':
            assert r.success or 'already training' in r.message, r.message
        elif name == 'stop':
            assert (r.success and 'stopped' in r.message) or \
                'no training run in progress' in r.message, r.message
    assert any(f.result().success for name, f in calls if name == 'train')
    assert proc.poll() is None
    final = clients['stop'].call_async(Trigger.Request())
    ros.wait_for(final.done, 'the last stop', timeout=120)
    assert ros.stop(proc) == 0
