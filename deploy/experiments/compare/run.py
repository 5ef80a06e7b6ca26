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
from deploy.launch.evaluate import RunResult


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

    record = recording_in_progress(figure_recording(out_dir, job.mode)) if job.record else None
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


def recording_in_progress(final: Path) -> Path:
    """Where a figures run records until the comparison is complete: an interrupted one
    leaves the recording a finished comparison's figures were drawn from."""
    return final.with_name(f"{final.stem}.partial{final.suffix}")


def _settle_recordings(jobs: Sequence[Job], out_dir: Path, keep: bool) -> None:
    """The recordings made in progress moved into place (``keep``), or removed."""
    for job in jobs:
        if not job.record:
            continue
        final = figure_recording(out_dir, job.mode)
        partial = recording_in_progress(final)
        if partial.exists():
            if keep:
                partial.replace(final)
            else:
                partial.unlink()


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
    try:
        rows = _run_all(jobs, n_jobs, out_dir, stop, on_start, on_done, pipeline)
    except BaseException:
        _settle_recordings(jobs, out_dir, keep=False)
        raise
    _settle_recordings(jobs, out_dir, keep=not stop.is_set())
    return rows


def _run_all(
    jobs: Sequence[Job],
    n_jobs: int,
    out_dir: Path,
    stop: threading.Event,
    on_start: Callable[[Job], None],
    on_done: Callable[[Job, CompareRow], None],
    pipeline: str,
) -> list[CompareRow]:
    indexed = list(enumerate(jobs))
    local = [(i, j) for i, j in indexed if pipeline == "inprocess" and not j.record]
    services = [(i, j) for i, j in indexed if not (pipeline == "inprocess" and not j.record)]
    rows: dict[int, CompareRow] = {}
    if local:
        import multiprocessing

        context = multiprocessing.get_context("spawn")  # no GL context or Zenoh state inherited
        with ProcessPoolExecutor(max_workers=n_jobs, mp_context=context) as pool:

            def in_worker(_i: int, job: Job) -> Future:
                return pool.submit(run_job_inprocess, str(job.scenario_path), job.overrides)

            rows |= _schedule(local, n_jobs, stop, in_worker, on_start, on_done)
    if services and not stop.is_set():
        token = uuid.uuid4().hex[:8]  # another comparison on this machine uses other prefixes
        endpoints = _Endpoints()
        with ThreadPoolExecutor(max_workers=n_jobs, thread_name_prefix="compare") as pool:

            def in_thread(i: int, job: Job) -> Future:
                return pool.submit(run_job, job, i, token, out_dir, endpoints, stop)

            rows |= _schedule(services, n_jobs, stop, in_thread, on_start, on_done)
    return [rows[i] for i in sorted(rows)]


def run_job_inprocess(scenario_path: str, overrides: tuple[str, ...]) -> RunResult:
    """One run in this (worker) process: the scenario file with its overrides."""
    from common.config import load_scenario
    from common.runtime import parse_overrides
    from deploy.launch.run_inprocess import run_scenario_inprocess

    return run_scenario_inprocess(load_scenario(scenario_path, parse_overrides(list(overrides))))


def _schedule(
    jobs: Sequence[tuple[int, Job]],
    n_jobs: int,
    stop: threading.Event,
    submit: Callable[[int, Job], Future],
    on_start: Callable[[Job], None],
    on_done: Callable[[Job, CompareRow], None],
) -> dict[int, CompareRow]:
    """``jobs`` (plan index, job), ``n_jobs`` submitted at a time; a future gives the run's
    row (a pipeline's) or its result (a worker's). On ``stop`` or an exception nothing more
    starts; the running jobs stop their services (the pool waits for them)."""
    rows: dict[int, CompareRow] = {}
    pending = list(jobs)
    running: dict[Future, tuple[int, Job]] = {}
    try:
        while pending or running:
            while pending and len(running) < n_jobs and not stop.is_set():
                i, job = pending.pop(0)
                on_start(job)
                running[submit(i, job)] = (i, job)
            if not running:
                break
            done, _ = wait(running, timeout=0.5, return_when=FIRST_COMPLETED)
            for future in done:
                i, job = running.pop(future)
                value = future.result()
                row = value if isinstance(value, CompareRow) else make_row(job, value)
                if not (stop.is_set() and row.detail == "interrupted"):
                    rows[i] = row
                    on_done(job, row)
    except BaseException:
        stop.set()
        for future in running:
            future.cancel()
        raise
    return rows


def make_figures(
    plan_: Plan, out_dir: Path, on_drawn: Callable[[str], None] = lambda _name: None
) -> list[Path]:
    """Per strategy, the thesis-style figures of the figures scenario's run (Figs. 5.10-5.17:
    image trajectory, end-effector velocity, plus feature error and joint velocities), and
    ``overlay.png`` of every strategy's image trajectory, error and speed. None when no run
    was recorded (``umay campaign --no-figures``). ``on_drawn(name)`` as each strategy's
    figures, then the overlay, are written (a second or two each: a progress bar's steps)."""
    from deploy.experiments.compare.plots import write_overlay
    from deploy.recording.plots import load_series, plot_series

    job = next((j for j in plan_.jobs if j.record), None)
    if job is None:
        return []
    converged_px = job.scenario.controller.converged_px
    written: list[Path] = []
    series = {}
    for mode in plan_.modes:
        rec = figure_recording(out_dir, mode)
        if rec.is_file():
            series[mode] = load_series(rec)  # read once: the mode's figures and the overlay
            written += plot_series(series[mode], rec.parent, converged_px, source=str(rec))
        on_drawn(mode)
    overlay = write_overlay(
        series,
        out_dir / "figures" / "overlay.png",
        converged_px,
        title=f"All strategies, scenario {plan_.figures_scenario!r}",
    )
    on_drawn("overlay")
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
