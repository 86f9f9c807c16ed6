"""The experiment report's robustness curves: each row's returned policies against each
disturbance profile's size.

Every seed's returned policy (the one its run file holds) runs ``sweep``'s held-out
disturbed episodes at each size; a row's point is the mean success rate over its seeds,
with a 95 % bootstrap interval over the seeds (the seeds are the independent runs; the
episodes of one policy are not).  Written: ``DIR/robustness.json`` (every policy's
points), ``DIR/robustness_<profile>.png`` and a table per profile in ``report.md``.
Q-learning rows are left out: a Q-table runs undisturbed only.

With ``replan`` (``ReplanSettings``) the curves are those of the returned policies' plans
re-planned as they run (``sapga eval --replan``; ``sweep``), the planner predicting for each
size's own latency; a hold task's planner hands over to the classical LQR
(``evaluation.hold_catch``).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from sapga_ros.evaluation.replan_settings import ReplanSettings, plannable
from sapga_ros.evaluation.sweep import sweep
from sapga_ros.io.atomic import write_inside
from sapga_ros.io.jsonfile import dumps
from sapga_ros.policies.runnable import policy_from_document
from sapga_ros.training.experiment_report import bootstrap_ci, row_method
from sapga_ros.training.run_files import run_path, stored_runs


@dataclass(frozen=True)
class CurveSettings:
    """What the curves measure: profiles (names or .yaml files), size factors, held-out
    episodes per policy and size, the seed of their draws."""

    profiles: tuple[str, ...]
    scales: tuple[float, ...]
    episodes: int
    seed: int = 0
    replan: ReplanSettings | None = None    # re-planned curves with these settings
    jobs: int = 1                   # threads of the re-planned episodes (the same results)


def _label(s: dict) -> str:
    return f"#{s['id']} {row_method(s)} ({s['problem']})"


def _row_points(out: Path, s: dict, profiles: list, settings: CurveSettings,
                points: list[dict]) -> dict[str, np.ndarray]:
    """(seeds x scales) success rates of row ``s`` per profile; ``points`` gets each one."""
    rates: dict[str, list] = {p.name: [] for p in profiles}
    for seed, run in stored_runs(out, s['id'], s['seeds']):
        doc = run.get('policy')
        if doc is None:
            continue
        policy = policy_from_document(doc, s['problem'],
                                      f"{run_path(out, s['id'], seed)}: run.policy")
        for p in profiles:
            rows = sweep(policy, s['delta'], p, settings.scales, settings.episodes,
                         settings.seed, settings.replan, 0, settings.jobs)
            rates[p.name].append([r['success_rate'] for r in rows])
            points += [{**r, 'experiment': s['id'], 'run_seed': seed} for r in rows]
    return {k: np.array(v, dtype=float).reshape(len(v), len(settings.scales))
            for k, v in rates.items()}


def _left_out(s: dict, settings: CurveSettings) -> str | None:
    """Why row ``s`` has no curves, or None."""
    if s['method'] == 'ql':
        return 'Q-learning: runs undisturbed only'
    if settings.replan is not None:
        from sim_nodes.problem import load_problem
        if not plannable(load_problem(s['problem'])):
            return 'a hold task without a classical LQR: not re-planned'
    return None


def robustness_section(out: Path, summaries: list[dict], settings: CurveSettings) -> list[str]:
    """Measure the curves of every row with exemplar policies; the report's lines."""
    from sapga_ros.viz.robustness_plot import curve_figures
    from sim_nodes.disturbance import load_disturbance
    profiles = [load_disturbance(name) for name in settings.profiles]
    curves: dict[str, dict] = {p.name: {} for p in profiles}
    tables: dict[str, list[str]] = {p.name: [] for p in profiles}
    points: list[dict] = []
    left_out = []
    for s in summaries:
        why = _left_out(s, settings)
        if why:
            left_out.append(f"#{s['id']} ({why})")
            continue
        rates = _row_points(out, s, profiles, settings, points)
        for p in profiles:
            a = rates[p.name]
            if not len(a):
                continue
            cis = [bootstrap_ci(list(a[:, j])) for j in range(a.shape[1])]
            curves[p.name][_label(s)] = [
                (x, float(a[:, j].mean()), cis[j]) for j, x in enumerate(settings.scales)]
            tables[p.name].append(f'| {_label(s)} | {len(a)} | ' + ' | '.join(
                f'{a[:, j].mean():.2f}' + (f' [{c[0]:.2f}, {c[1]:.2f}]' if c else '')
                for j, c in enumerate(cis)) + ' |')
    measured = {k: v for k, v in asdict(settings).items() if k != 'jobs'}
    write_inside(out, 'robustness.json', dumps({'settings': measured, 'points': points},
                                               indent=1))
    planned = settings.replan is not None
    paths = curve_figures(curves, out, 'robustness_', 'success rate (mean over seeds)',
                          f'{settings.episodes} held-out episodes per policy and size'
                          + (', re-planned' if planned else ''))
    lines = [f'Each row\'s returned policies, {settings.episodes} held-out disturbed episodes '
             f'per policy and size (draw seed {settings.seed}); success = entered S_δ (hold '
             'problems: hold fraction ≥ 0.9); mean success rate over the row\'s seeds with a '
             '95 % bootstrap interval over the seeds.', '']
    if planned:
        r = settings.replan
        lines += [f'Re-planned as they run (`sapga eval --replan`): {r.replan_rounds} rounds '
                  f'of 16 mutants over a window of {r.replan_window} steps every '
                  f'{r.replan_every} step(s), mutation seed {r.replan_seed}, '
                  + (f'the model fitted as it runs (prior spread {r.replan_fit:g})'
                     if r.replan_fit else 'the nominal model')
                  + (f', acting on the Kalman-filtered state (sensor sigma {r.replan_filter:g})'
                     if r.replan_filter else '')
                  + '; the planner predicts for each size\'s own latency.', '']
    if left_out:
        lines += [f'Left out: {", ".join(left_out)}.', '']
    head = ' | '.join(f'x{x:g}' for x in settings.scales)
    for p, path in zip(profiles, paths):
        lines += [f'**{p.name}**', '', f'| row | seeds | {head} |',
                  '|---|---|' + '---|' * len(settings.scales)] + tables[p.name] + [
                  '', f'![robustness {p.name}]({path.name})', '']
    return lines
