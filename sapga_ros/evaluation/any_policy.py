"""Any policy file the package writes: an exemplar policy (sapga-policy/1) or a
Q-learning table (sapga-qtable/1), loaded and run for one recorded episode."""
from __future__ import annotations

from pathlib import Path

from sapga_ros.errors import SapgaError


def load_any_policy(path: str):
    """A sapga-policy/1 or sapga-qtable/1 file, told apart by its ``format`` field."""
    from sapga_ros.exemplars.policy import load_policy
    from sapga_ros.optim.qlearning import FORMAT as QFORMAT, parse_json, qtable_from_document
    from sapga_ros.exemplars.policy import MAX_POLICY_BYTES
    p = Path(path)
    try:
        size = p.stat().st_size
    except OSError as exc:
        raise SapgaError(f'{path}: cannot read ({exc.strerror})') from exc
    if size > MAX_POLICY_BYTES:
        return load_policy(p)  # refuses with the size message
    with open(p, 'rb') as f:
        head = f.read(4096)
    if QFORMAT.encode() in head:
        doc = parse_json(p.read_bytes(), str(p))
        if isinstance(doc, dict) and doc.get('format') == QFORMAT:
            return qtable_from_document(doc, str(p))
    return load_policy(p)


def run_policy_episode(policy, delta: float, max_steps: int | None = None):
    from sapga_ros.evaluation.evaluator import Evaluator
    from sapga_ros.optim.qlearning import QTable
    if isinstance(policy, QTable):
        return policy.episode(delta, max_steps)
    return Evaluator(policy.problem, delta, max_steps).episode(policy)
