"""Running a comparison: a thread per running job (each waiting on its own four processes), the
figures, the outputs."""

from __future__ import annotations

import threading
import uuid
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from pathlib import Path

from deploy.experiments.compare.plan import Job, Plan
from deploy.experiments.compare.rows import CompareRow, make_row, rows_csv, rows_json
from deploy.experiments.compare.summary import summary_markdown


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


def run_all(
    jobs: Sequence[Job],
    n_jobs: int,
    out_dir: Path,
    stop: threading.Event,
    on_start: Callable[[Job], None] = lambda _job: None,
    on_done: Callable[[Job, CompareRow], None] = lambda _job, _row: None,
) -> list[CompareRow]:
    """Run ``jobs``, ``n_jobs`` at a time; the rows in plan order. When ``stop`` is set (or
    Ctrl-C arrives), running jobs stop their services and the rest never start; the rows of
    the runs that finished are returned."""
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
