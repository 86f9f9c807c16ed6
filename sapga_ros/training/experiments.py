"""The experiment engine: many seeds of each experiment of a set, run in worker
processes, each run's result written to ``DIR/runs/`` the moment it finishes.

Rerunning with the same ``DIR`` skips the runs already there (resume after a kill); a run
file of other settings is refused, never mixed in.  When every run is done the summaries
(``summary.json``, ``summary.md``, ``runs.json``) are written from the run files
(``experiment_report``); the figures and ``report.md`` are drawn from them by
``sapga_ros.viz.report``.  Each run is deterministic in its seed, so the order in which
workers finish changes nothing.
"""
from __future__ import annotations

import multiprocessing
import os
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import asdict
from pathlib import Path
from typing import BinaryIO, Callable, Iterator

from sapga_ros.errors import ConfigError, DataFileError
from sapga_ros.io.atomic import write_atomic
from sapga_ros.io.jsonfile import dumps, write_json
from sapga_ros.training.experiment_report import markdown_table, row_method, summarise
from sapga_ros.training.experiment_checks import check_request, subdir
from sapga_ros.training.experiment_set import MAX_STEPS, Experiment, LimitSearch, run_seeds
from sapga_ros.training.run_files import read_run, run_path as _run_path, run_state
from sapga_ros.optim.qlearner import LANE_BLOCK

MAX_RUNS = 100_000           # runs of one invocation at most


def run_path(out: Path, exp: Experiment, seed: int) -> Path:
    return _run_path(out, exp.id, seed)


UNSET = (('catch', 'none'), ('disturbance', 'none'), ('episodes', 1), ('robust_stat', 'mean'),
         ('redraw', False), ('catch_delay', 0), ('delay', 0))


def run_key(name: str, exp: Experiment, seed: int, budget: int) -> dict:
    """What a run's result depends on (not the row's description): a stored run is reused
    only for the same key."""
    settings = {k: v for k, v in asdict(exp).items()
                if k not in ('paper', 'group', 'seeds') and (k, v) not in UNSET}
    return {'set': name, 'experiment': settings, 'seed': seed, 'steps': budget}


def _job(args: tuple) -> list[tuple[tuple, dict]]:
    """((experiment, seed, budget), run) of each seed of a job (experiment, seeds, budget);
    for a physical-limit search (search, (), beam width): ((search, None, width), the
    search's document)."""
    exp, seeds, budget = args
    if isinstance(exp, LimitSearch):
        try:
            return [((exp, None, budget), _search(exp, budget))]
        except Exception as exc:      # raised by the caller once every run is written
            return [((exp, None, budget), exc)]
    return [((exp, seed, budget), run)
            for seed, run in zip(seeds, run_seeds(exp, list(seeds), budget))]


def plan_jobs(pending: list[tuple], workers: int,
              searches: list[tuple[LimitSearch, int]] = ()) -> list[tuple]:
    """The jobs (experiment, seeds, budget) of the pending runs (experiment, seed, budget),
    longest first.  A Q-learning row's seeds are grouped to learn side by side (at most
    ``LANE_BLOCK`` lanes; as many groups as workers while seeds last); any other run is a
    job of its own.  The physical-limit ``searches`` (search, beam width) are jobs
    (search, (), width) after the jobs of several seeds and before the single runs: a search
    takes about as long as a long single run, and in the pool it no longer waits for every
    run to finish."""
    rows: dict[tuple, list[int]] = {}
    jobs = []
    for exp, seed, budget in pending:
        if exp.method == 'ql':
            rows.setdefault((exp, budget), []).append(seed)
        else:
            jobs.append((exp, (seed,), budget))
    for (exp, budget), seeds in rows.items():
        groups = min(len(seeds), max(-(-len(seeds) // LANE_BLOCK), workers))
        size, extra = divmod(len(seeds), groups)
        at = 0
        for g in range(groups):
            n = size + (g < extra)
            jobs.append((exp, tuple(seeds[at:at + n]), budget))
            at += n
    jobs.sort(key=lambda job: -job[2] * len(job[1]))
    at = sum(1 for job in jobs if len(job[1]) > 1)
    return jobs[:at] + [(search, (), width) for search, width in searches] + jobs[at:]


class _Progress:
    """A bar over runs with ETA on a terminal (tqdm); a line per finished run otherwise."""

    def __init__(self, total: int, done: int, log: Callable) -> None:
        self.bar = None
        self.log = log
        self.total, self.done, self.start = total, done, time.perf_counter()
        if sys.stderr.isatty() and log is print:
            from tqdm import tqdm
            self.bar = tqdm(total=total, initial=done, unit='run', file=sys.stderr)

    def step(self, text: str) -> None:
        self.done += 1
        if self.bar is not None:
            self.bar.set_postfix_str(text)
            self.bar.update(1)
        else:
            self.log(f'  run {self.done}/{self.total} done: {text}')

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def run_experiments(name: str, out: str | os.PathLike, only: list[int] | None = None,
                    seeds: int | None = None, scale: float = 1.0,
                    workers: int | None = None, log=print, backend: str = 'local',
                    address: str | None = None) -> list[dict]:
    """Run (a part of) an experiment set, resuming from ``out/runs``; write the summaries.

    ``backend``: ``local`` (worker processes on this machine) or ``ray`` (tasks of the Ray
    cluster at ``address``; a local Ray instance when it is None).  The set, the options and
    the stored files are checked before any run starts; a damaged run file is reported and
    run again."""
    exps, n_seeds, searches = check_request(name, only, seeds, scale, backend, address)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    subdir(out, 'runs')
    subdir(out, 'limits')
    budgets = {e.id: min(MAX_STEPS, max(1000, int(e.steps * scale))) for e in exps}
    row_seeds = {e.id: e.seeds if e.seeds is not None and seeds is None else n_seeds
                 for e in exps}
    if sum(row_seeds.values()) > MAX_RUNS:
        raise ConfigError(f'{sum(row_seeds.values())} runs requested, at most {MAX_RUNS} '
                          'in one invocation (fewer --seeds or --only)')
    done: dict[tuple[int, int], dict] = {}
    pending = []
    for exp in exps:
        for seed in range(row_seeds[exp.id]):
            key = run_key(name, exp, seed, budgets[exp.id])
            run, damaged = run_state(run_path(out, exp, seed), key, seed)
            if run is None:
                if damaged:
                    log(f'{damaged[:300]}; running it again')
                pending.append((exp, seed, budgets[exp.id]))
            else:
                done[exp.id, seed] = run['final']
    log(f'{name}: {len(exps)} experiments x {n_seeds} seeds; {len(done)} runs done before, '
        f'{len(pending)} to run')
    searching = [(search, _width(search, scale)) for search in searches
                 if not _found(out, search, log)]
    if backend == 'ray' and address and (pending or searching):
        from sapga_ros.training.ray_address import reach
        reach(address)
    started = time.perf_counter()
    reused = len(done)
    progress = _Progress(len(done) + len(pending), len(done), log)
    workers = workers or os.cpu_count() or 1
    failed = []
    try:
        for finished in _execute(plan_jobs(pending, workers, searching), workers, backend,
                                 address):
            for (exp, seed, budget), run in finished:
                if isinstance(exp, LimitSearch):   # a search's failure waits for the runs
                    if isinstance(run, Exception):
                        failed.append(run)
                    else:
                        _write_limit(out, exp, run, log)
                    continue
                key = run_key(name, exp, seed, budget)
                write_json(run_path(out, exp, seed), {'key': key, 'run': run})
                done[exp.id, seed] = run['final']
                progress.step(f'#{exp.id} seed {seed}: delta* '
                              f"{run['final']['delta_star']:.4f}")
    finally:
        progress.close()
    if failed:
        raise failed[0]
    command = ' '.join(['sapga experiment', name, '--out', str(out)]
                       + (['--only', ','.join(map(str, only))] if only else [])
                       + (['--seeds', str(seeds)] if seeds is not None else [])
                       + (['--scale', str(scale)] if scale != 1.0 else [])
                       + (['--backend', backend] if backend != 'local' else []))
    write_json(out / 'experiment.json', {
        'name': name, 'command': command, 'seeds': n_seeds, 'scale': scale,
        'backend': backend, 'wall_s': time.perf_counter() - started,
        'runs_run': len(done) - reused, 'runs_reused': reused})
    return _summarise(name, exps, row_seeds, budgets, out, log)


def _width(search: LimitSearch, scale: float) -> int:
    """The beam width of a search in a run of the set at ``scale``."""
    return max(200, int(search.width * min(scale, 1.0)))


def _found(out: Path, search: LimitSearch, log) -> bool:
    """Whether ``out/limits/`` holds a sound file of the search (a damaged one is said and
    searched again)."""
    from sapga_ros.analysis.limit_file import read_limit
    path = out / 'limits' / search.file_name
    if not (path.exists() or path.is_symlink()):
        return False
    try:
        read_limit(path)
        return True
    except DataFileError as exc:
        log(f'{str(exc)[:300]}; searching it again')
        return False


def _search(search: LimitSearch, width: int) -> dict:
    """A physical-limit search (``sapga_ros.analysis.limit``), as the document its file
    holds (in a worker)."""
    from sapga_ros.analysis.limit import beam_limit
    from sapga_ros.analysis.limit_file import limit_document
    from sim_nodes.goal import alternative_goal
    from sim_nodes.problem import load_problem
    problem = load_problem(search.problem)
    if search.alternative_goal:
        problem = alternative_goal(problem)
    start = time.perf_counter()
    limit = beam_limit(problem, width=width, cells=search.cells, per_cell=search.per_cell)
    return {**limit_document(limit), 'alternative_goal': search.alternative_goal,
            'seconds': time.perf_counter() - start}


def _write_limit(out: Path, search: LimitSearch, doc: dict, log) -> None:
    """Write a finished search into ``out/limits/``."""
    write_json(out / 'limits' / search.file_name, doc)
    log(f'limit of {search.problem}{" (alternative goal)" if search.alternative_goal else ""}: '
        f"delta {doc['delta']:.5f} at step {doc['step']}")


def _execute(jobs: list[tuple], workers: int, backend: str = 'local',
             address: str | None = None):
    """Each job's [(run, result)] as the job finishes: in worker processes (``local``;
    here, for one worker) or as tasks of a Ray cluster (``ray``)."""
    if backend == 'ray':
        yield from _execute_ray(jobs, workers, address)
        return
    if workers == 1 or len(jobs) <= 1:
        for job in jobs:
            yield _job(job)
        return
    # spawned, not forked: a fork of a process whose numba kernels already ran threads
    # (OpenMP) is unsafe and is killed
    context = multiprocessing.get_context('spawn')
    with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=context) as pool:
        futures = {pool.submit(_job, job) for job in jobs}
        while futures:
            finished, futures = wait(futures, return_when=FIRST_COMPLETED)
            for future in finished:
                yield future.result()


def _execute_ray(jobs: list[tuple], workers: int, address: str | None):
    """The jobs as Ray tasks (one CPU each): on the cluster at ``address``, or on a local
    Ray instance started here with ``workers`` CPUs and stopped at the end.  Every node of
    a cluster needs this package installed (the tasks import it)."""
    if not jobs:
        return
    import ray
    started = not ray.is_initialized()
    if started:
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    try:
        task = ray.remote(num_cpus=1, max_retries=2)(_job)
        pending = [task.remote(job) for job in jobs]
        while pending:
            finished, pending = ray.wait(pending, num_returns=1)
            for ref in finished:
                yield ray.get(ref)
    finally:
        if started:
            ray.shutdown()


def _summarise(name: str, exps: list[Experiment], row_seeds: dict, budgets: dict,
               out: Path, log) -> list[dict]:
    """Write summary.json, summary.md, and runs.json from the run files, one
    run in memory at a time (``runs.json`` is written as the runs are read)."""
    summaries = []

    def runs(f: BinaryIO, exp: Experiment) -> Iterator[dict]:
        for i, seed in enumerate(range(row_seeds[exp.id])):
            path = run_path(out, exp, seed)
            key, run = read_run(path, seed)
            if key != run_key(name, exp, seed, budgets[exp.id]):
                raise ConfigError(f'{path}: changed while the experiment ran (other settings)')
            f.write(((', ' if i else '') + dumps(run)).encode())
            yield run

    def write_runs(f: BinaryIO) -> None:
        f.write(b'{')
        for i, exp in enumerate(exps):
            f.write(f'{", " if i else ""}"{exp.id}": ['.encode())
            summaries.append(summarise(exp, runs(f, exp), budgets[exp.id]))
            f.write(b']')
        f.write(b'}')

    write_atomic(out / 'runs.json', write_runs)
    for exp, s in zip(exps, summaries):
        f = s['final']
        style = f' ({exp.style})' if exp.method == 'sapga' else ''
        log(f'#{exp.id} {row_method(s)}{style} on {exp.problem}, delta {exp.delta}, '
            f'{budgets[exp.id]:,d} steps: achieved '
            f"{f['achieved']}/{f['runs']}, best value {f['best_value_mean']:.1f} +- "
            f"{f['best_value_std']:.1f}, delta* {f['delta_star_mean']:.4f} +- "
            f"{f['delta_star_std']:.4f}"
            + (f", hold fraction {f['hold_fraction_mean']:.3f} +- {f['hold_fraction_std']:.3f}"
               f" ({f['holding']}/{f['runs']} >= 0.95)" if 'holding' in f else ''))
    write_json(out / 'summary.json', summaries, indent=1)
    write_atomic(out / 'summary.md', markdown_table(summaries))
    return summaries
