"""Running a comparison: a thread per running job (each waiting on its own four processes), or
with ``pipeline="inprocess"`` a pool of worker processes each running the lockstep loop in
itself (:mod:`services.pipeline`: the same result to the last bit, tests/integration/
test_pipeline_vs_distributed.py); the figures, the outputs."""

from __future__ import annotations

import threading
import uuid
from collections.abc import Callable, Sequence
from concurrent.futures import (
    FIRST_COMPLETED,
    Future,
    ProcessPoolExecutor,
    ThreadPoolExecutor,
    wait,
)
from pathlib import Path

from deploy.experiments.compare.plan import Job, Plan
from deploy.experiments.compare.rows import CompareRow, make_row, rows_csv, rows_json
from deploy.experiments.compare.summary import summary_markdown
from deploy.experiments.evaluate import RunResult


# --- running -----------------------------------------------------------------------------------
class _Endpoints:
    """Free loopback ports, never the same one twice in a comparison (a port freed by one
    pipeline could otherwise be handed to the next before the first one is done with it)."""

    def __init__(self) -> None:
        self._used: set[str] = set()
        self._lock = threading.Lock()

    def take(self) -> str:
        from common.session import free_tcp_endpoint

        with self._lock:
            while True:
                endpoint = free_tcp_endpoint()
                if endpoint not in self._used:
                    self._used.add(endpoint)
                    return endpoint


def job_label(job: Job) -> str:
    return f"{job.scenario.name} · {job.mode}"


def run_job(
    job: Job,
    index: int,
    token: str,
    out_dir: Path,
    endpoints: _Endpoints,
    stop: threading.Event,
) -> CompareRow:
    """One closed-loop run under its own prefix, port and log directory."""
    import shutil

    from deploy.launch.run import run_once

    record = figure_recording(out_dir, job.mode) if job.record else None
    log_dir = out_dir / "logs" / job.scenario.name / job.mode
    shutil.rmtree(log_dir, ignore_errors=True)  # the services append: keep this run's only
    result = run_once(
        str(job.scenario_path),
        job.scenario,
        list(job.overrides),
        prefix=f"umay/compare-{token}/{index:03d}",
        log_dir=log_dir,
        listen=endpoints.take(),
        quiet=True,
        record=record,
        stop=stop,
    )
    return make_row(job, result)


def figure_recording(out_dir: Path, mode: str) -> Path:
    return out_dir / "figures" / mode / "run.mcap"


PIPELINES = ("distributed", "inprocess")


def run_all(
    jobs: Sequence[Job],
    n_jobs: int,
    out_dir: Path,
    stop: threading.Event,
    on_start: Callable[[Job], None] = lambda _job: None,
    on_done: Callable[[Job, CompareRow], None] = lambda _job, _row: None,
    pipeline: str = "distributed",
) -> list[CompareRow]:
    """Run ``jobs``, ``n_jobs`` at a time; the rows in plan order. When ``stop`` is set (or
    Ctrl-C arrives), running jobs stop and the rest never start; the rows of the runs that
    finished are returned. ``pipeline="inprocess"`` runs the jobs that are not recorded in
    worker processes of their own; the recorded ones (the figures scenario's) still go through
    the four processes, whose messages the recording is made of."""
    if pipeline not in PIPELINES:
        raise ValueError(f"pipeline: {pipeline!r} is not one of {PIPELINES}")
    if pipeline == "distributed":
        return _run_threaded(jobs, n_jobs, out_dir, stop, on_start, on_done)
    indexed = list(enumerate(jobs))
    local = [(i, j) for i, j in indexed if not j.record]
    recorded = [(i, j) for i, j in indexed if j.record]
    rows = dict(_run_inprocess(local, n_jobs, stop, on_start, on_done))
    if not stop.is_set() and recorded:
        done = _run_threaded([j for _, j in recorded], n_jobs, out_dir, stop, on_start, on_done)
        rows.update(zip((i for i, _ in recorded), done, strict=False))
    return [rows[i] for i in sorted(rows)]


def run_job_inprocess(scenario_path: str, overrides: tuple[str, ...]) -> RunResult:
    """One run in this (worker) process: the scenario file with its overrides."""
    from common.config import load_scenario
    from common.runtime import parse_overrides
    from deploy.launch.run_inprocess import run_scenario_inprocess

    return run_scenario_inprocess(load_scenario(scenario_path, parse_overrides(list(overrides))))


def _run_inprocess(
    jobs: Sequence[tuple[int, Job]],
    n_jobs: int,
    stop: threading.Event,
    on_start: Callable[[Job], None],
    on_done: Callable[[Job, CompareRow], None],
) -> list[tuple[int, CompareRow]]:
    """``jobs`` (plan index, job) in a pool of ``n_jobs`` worker processes."""
    import multiprocessing

    rows: list[tuple[int, CompareRow]] = []
    pending = list(jobs)
    running: dict[Future, tuple[int, Job]] = {}
    context = multiprocessing.get_context("spawn")  # no GL context or Zenoh state inherited
    with ProcessPoolExecutor(max_workers=n_jobs, mp_context=context) as pool:
        try:
            while pending or running:
                while pending and len(running) < n_jobs and not stop.is_set():
                    i, job = pending.pop(0)
                    on_start(job)
                    future = pool.submit(run_job_inprocess, str(job.scenario_path), job.overrides)
                    running[future] = (i, job)
                if not running:
                    break
                done, _ = wait(running, timeout=0.5, return_when=FIRST_COMPLETED)
                for future in done:
                    i, job = running.pop(future)
                    row = make_row(job, future.result())
                    rows.append((i, row))
                    on_done(job, row)
        except BaseException:
            stop.set()
            for future in running:
                future.cancel()
            raise
    return rows


def _run_threaded(
    jobs: Sequence[Job],
    n_jobs: int,
    out_dir: Path,
    stop: threading.Event,
    on_start: Callable[[Job], None] = lambda _job: None,
    on_done: Callable[[Job, CompareRow], None] = lambda _job, _row: None,
) -> list[CompareRow]:
    """The four-process pipelines, ``n_jobs`` at a time (see :func:`run_all`)."""
    token = uuid.uuid4().hex[:8]  # another comparison on this machine uses other prefixes
    endpoints = _Endpoints()
    rows: dict[int, CompareRow] = {}
    pending = list(enumerate(jobs))
    running: dict[Future, int] = {}
    with ThreadPoolExecutor(max_workers=n_jobs, thread_name_prefix="compare") as pool:
        try:
            while pending or running:
                while pending and len(running) < n_jobs and not stop.is_set():
                    i, job = pending.pop(0)
                    on_start(job)
                    running[pool.submit(run_job, job, i, token, out_dir, endpoints, stop)] = i
                if not running:
                    break
                done, _ = wait(running, timeout=0.5, return_when=FIRST_COMPLETED)
                for future in done:
                    i = running.pop(future)
                    row = future.result()
                    if not (stop.is_set() and row.detail == "interrupted"):
                        rows[i] = row
                        on_done(jobs[i], row)
        except BaseException:
            stop.set()  # the running jobs stop their services; the pool waits for them
            raise
    return [rows[i] for i in sorted(rows)]


def make_figures(plan_: Plan, out_dir: Path) -> list[Path]:
    """Per strategy, the thesis-style figures of the figures scenario's run (Figs. 5.10-5.17:
    image trajectory, end-effector velocity, plus feature error and joint velocities), and
    ``overlay.png`` of every strategy's image trajectory, error and speed."""
    from deploy.experiments.compare.plots import write_overlay
    from deploy.recording.plots import load_series, plot_series

    job = next(j for j in plan_.jobs if j.record)
    converged_px = job.scenario.controller.converged_px
    written: list[Path] = []
    series = {}
    for mode in plan_.modes:
        rec = figure_recording(out_dir, mode)
        if rec.is_file():
            series[mode] = load_series(rec)  # read once: the mode's figures and the overlay
            written += plot_series(series[mode], rec.parent, converged_px, source=str(rec))
    overlay = write_overlay(
        series,
        out_dir / "figures" / "overlay.png",
        converged_px,
        title=f"All strategies, scenario {plan_.figures_scenario!r}",
    )
    if overlay is not None:
        written.append(overlay)
    return written


def write_outputs(
    plan_: Plan, rows: Sequence[CompareRow], out_dir: Path, figures: Sequence[Path], note: str = ""
) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path, json_path, md_path = (
        out_dir / "results.csv",
        out_dir / "results.json",
        out_dir / "summary.md",
    )
    csv_path.write_text(rows_csv(rows))
    json_path.write_text(rows_json(rows))
    relative = [str(p.relative_to(out_dir)) for p in figures]
    md_path.write_text(summary_markdown(rows, plan_.modes, plan_.scenario_names, relative, note))
    return [csv_path, json_path, md_path]
