"""Any policy file the package writes: an exemplar policy (sapga-policy/1) or a
Q-learning table (sapga-qtable/1), loaded and run for one recorded episode at the delta
``policy_delta`` gives."""
from __future__ import annotations

from pathlib import Path

from sapga_ros.errors import SapgaError
from sapga_ros.io.bounded import open_regular, read_bounded
from sim_nodes.params import DELTA


def load_any_policy(path: str):
    """A sapga-policy/1 or sapga-qtable/1 file, told apart by its ``format`` field."""
    from sapga_ros.exemplars.policy import load_policy
    from sapga_ros.optim.qlearning import FORMAT as QFORMAT, parse_json, qtable_from_document
    from sapga_ros.exemplars.policy import MAX_POLICY_BYTES
    p = Path(path)
    try:
        with open_regular(p) as f:
            head = f.read(4096)
    except OSError as exc:
        raise SapgaError(f'{path}: cannot read ({exc.strerror or exc})') from exc
    if QFORMAT.encode() in head:
        try:
            data = read_bounded(p, MAX_POLICY_BYTES)
        except OSError as exc:
            raise SapgaError(f'{path}: cannot read ({exc.strerror or exc})') from exc
        doc = parse_json(data, str(p))
        if isinstance(doc, dict) and doc.get('format') == QFORMAT:
            return qtable_from_document(doc, str(p))
    return load_policy(p)


def run_policy_episode(policy, delta: float, max_steps: int | None = None):
    from sapga_ros.evaluation.evaluator import Evaluator
    from sapga_ros.optim.qlearning import QTable
    if isinstance(policy, QTable):
        return policy.episode(delta, max_steps)
    return Evaluator(policy.problem, delta, max_steps).episode(policy)


def policy_delta(policy, given: float | None = None) -> float:
    """The delta a policy's episode runs at: ``given``, else the policy's training delta
    (``meta.delta``, if a valid delta), else the problem's (``sapga eval`` and the launches
    alike)."""
    if given is None:
        meta = policy.meta.get('delta') if isinstance(policy.meta, dict) else None
        given = meta if DELTA.reason(meta) is None else None
    return policy.problem.resolve('delta', given)
