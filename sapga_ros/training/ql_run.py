"""The Q-learning baseline's training run (SPEC 3.4): chunks of ``learn`` with progress
reports, checkpoints and a final greedy episode, returning a ``TrainResult``."""
from __future__ import annotations

import math
import time

import numpy as np

from sapga_ros import __version__
from sapga_ros.errors import CheckpointError
from sapga_ros.io.checkpoint import load_checkpoint, save_checkpoint
from sapga_ros.optim.qlearning import CHUNK_STEPS, QTable, learn
from sapga_ros.training.loop import TrainResult
from sim_nodes.goal import goal_arrays
from sim_nodes.models import model_id
from sim_nodes.problem import load_problem


def train_ql(config, progress=None, should_stop=None) -> 'object':
    """Run the Q-learning baseline as configured (a ``TrainConfig``); it ends early, keeping
    what it learnt, once ``should_stop()`` is true (checked every chunk of steps)."""
    pr = load_problem(config.problem)
    delta = float(pr.default_delta if config.delta is None else config.delta)
    cells = pr.ql_tiles_per_dim ** len(pr.ql_state_indices)
    settings = {'problem': pr.name, 'method': 'ql', 'delta': delta, 'seed': config.seed,
                'epsilon': pr.ql_epsilon, 'eta': pr.ql_eta}
    if config.resume:
        if not config.checkpoint:
            raise CheckpointError('--resume needs --checkpoint DIR')
        meta, arrays = load_checkpoint(config.checkpoint)
        if meta.get('run') != settings:
            raise CheckpointError(f'{config.checkpoint}: checkpoint is of another run '
                                  f'({meta.get("run")}), not {settings}')
        try:
            q, visited, rng = arrays['q'], arrays['visited'], arrays['rng']
            steps, episodes = int(meta['steps']), int(meta['episodes'])
            best_value, dstar = float(meta['best_value']), float(meta['delta_star'])
        except (KeyError, ValueError) as exc:
            raise CheckpointError(f'{config.checkpoint}: malformed run state ({exc})') from exc
        if q.shape != (cells, len(pr.actions)):
            raise CheckpointError(f'{config.checkpoint}: Q-table shape {q.shape}')
        history = list(meta.get('history', []))
    else:
        q = np.zeros((cells, len(pr.actions)))
        visited = np.zeros(cells, dtype=np.bool_)
        # splitmix64 of the seed: a non-zero xorshift state
        z = (config.seed + 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
        rng = np.array([(z ^ (z >> 31)) or 1], dtype=np.uint64)
        steps = episodes = 0
        best_value, dstar = -math.inf, math.inf
        history = []
    idx = np.array(pr.ql_state_indices, dtype=np.int64)
    low = pr.low[idx]
    width = (pr.high[idx] - low) / pr.ql_tiles_per_dim
    consts = (model_id(pr.model), pr.initial_state, pr.params(), pr.action_values, idx, low,
              width, pr.ql_tiles_per_dim, *goal_arrays(pr), pr.is_angle, delta, pr.n_step,
              pr.ql_epsilon, pr.ql_eta, 1.0)
    max_eps = CHUNK_STEPS  # an episode has at least one step
    ep_r, ep_s, ep_d = np.empty(max_eps), np.empty(max_eps, np.int64), np.empty(max_eps)
    start = time.perf_counter()
    steps_at_start = steps
    chunks = 0
    while steps < config.steps and not (should_stop and should_stop()):
        budget = min(CHUNK_STEPS, config.steps - steps)
        done, n_ep = learn(consts[0], q, visited, rng, *consts[1:], budget, ep_r, ep_s, ep_d)
        steps += int(done)
        episodes += int(n_ep)
        if n_ep:
            best_value = max(best_value, float(ep_r[:n_ep].max()))
            dstar = min(dstar, float(ep_d[:n_ep].min()))
        elapsed = time.perf_counter() - start
        row = {'episodes': episodes, 'steps': steps, 'best_value': best_value,
               'delta_star': dstar, 'achieved': dstar <= delta,
               'steps_per_s': (steps - steps_at_start) / max(elapsed, 1e-9)}
        history.append(row)
        if progress:
            progress(row)
        chunks += 1
        stopping = steps >= config.steps or bool(should_stop and should_stop())
        if config.checkpoint and (chunks % 10 == 0 or stopping):
            save_checkpoint(config.checkpoint,
                            {'run': settings, 'steps': steps, 'episodes': episodes,
                             'best_value': best_value, 'delta_star': dstar,
                             'history': history},
                            {'q': q, 'visited': visited, 'rng': rng})
    table = QTable(pr, q, visited, {})
    greedy_ep = table.episode(delta)
    table.meta = {'value': greedy_ep.ret, 'delta_star': greedy_ep.delta_star,
                  'steps_to_end': greedy_ep.steps, 'reached': greedy_ep.reached,
                  'best_training_value': best_value, 'run_delta_star': dstar, 'delta': delta,
                  'seed': config.seed, 'steps': steps, 'episodes': episodes, 'method': 'ql',
                  'epsilon': pr.ql_epsilon, 'eta': pr.ql_eta, 'gamma': 1.0,
                  'software': f'sapga_ros {__version__}',
                  'time': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())}
    return TrainResult(table, history, {'steps': steps, 'episodes': episodes,
                                        'best_value': best_value, 'delta_star': dstar})
