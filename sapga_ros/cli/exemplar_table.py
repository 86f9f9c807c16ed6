"""Looking at a policy's exemplars: a table with referral counts (``sapga exemplars``).

Knowledge extraction after optimisation (paper section 2): each exemplar as its policy file
writes it, how often the episode's selector reported it and whether it was referred to.
The pictures are in ``sapga_ros.viz.exemplar_plot``.
"""
from __future__ import annotations

import numpy as np

from sapga_ros.policies.exemplar import ExemplarPolicy


def exemplar_table(policy: ExemplarPolicy, counts: np.ndarray,
                   referred: np.ndarray | None = None) -> list[dict]:
    """One row per exemplar: index, uses (steps that reported it), referred, its fields."""
    rows = []
    for j in range(len(policy)):
        row = {'index': j, 'uses': int(counts[j])}
        if referred is not None:
            row['referred'] = bool(referred[j])
        row.update(policy.exemplar_document(j))
        rows.append(row)
    return rows


def format_table(policy: ExemplarPolicy, rows: list[dict]) -> list[str]:
    """The table as text lines: a header, then one line per exemplar."""
    names = policy.problem.state_names
    keys = [k for k in rows[0] if k not in ('index', 'uses', 'referred')] if rows else []
    head = f"{'#':>4} {'uses':>5}"
    for key in keys:
        width = 11 * len(names) + len(names) - 1
        head += f' {key:>9}' if key in ('action', 'value') else f'  {key:<{width}}'
    lines = [head]
    for r in rows:
        line = f"{r['index']:>4} {r['uses']:>5}"
        for key in keys:
            if isinstance(r[key], list):
                line += '  ' + ' '.join(f'{v:>11.4f}' for v in r[key])
            else:
                line += f' {r[key]:>9g}'
        lines.append(line)
    return lines
