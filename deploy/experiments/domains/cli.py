"""``umay domains`` on the command line: draw the grid's starts, run every strategy on each
through an executor, write the study (``domains.json``, ``runs.jsonl`` as runs finish,
``report.md``, a heat map per strategy). Parsing imports nothing heavy."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from deploy.arguments import a_seed, at_least_one
from deploy.consoles import progress_bar, progress_console
from deploy.exit_codes import EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_OK
from deploy.interrupts import stop_requested

if TYPE_CHECKING:
    from deploy.experiments.domains.study import DomainRecord, StudyDefinition


def add_domains_parser(sub: argparse._SubParsersAction) -> None:
    """The ``domains`` subcommand, for :func:`deploy.cli.build_parser`."""
    from deploy.experiments.domains.study import DEFAULT_STUDY

    p = sub.add_parser(
        "domains",
        help="convergence domains: every strategy over a grid of large initial displacements",
        description="Every strategy over a grid of starts (turn about the optical axis, "
        "distance, depth; deploy/domains/study.toml) with seeded draws per cell: heat maps, "
        "success by band and one named cause per failure, on --jobs processes or a Dask "
        "cluster. An interrupted study resumes with --resume (docs/domains.md).",
    )
    p.add_argument(
        "--study",
        default=str(DEFAULT_STUDY),
        metavar="FILE.toml",
        help="the study's grid, draws and seed (default: deploy/domains/study.toml)",
    )
    p.add_argument("--seed", type=a_seed, default=None, help="instead of the study file's seed")
    p.add_argument(
        "--draws", type=at_least_one, default=None, help="draws per cell, instead of the file's"
    )
    p.add_argument(
        "--cells",
        default=None,
        metavar="A:B",
        help="only cells A to B-1 of the grid (a slice, for a quick look; indices as in the file)",
    )
    p.add_argument("--modes", nargs="+", default=None, metavar="MODE", help="strategies")
    p.add_argument(
        "--pipeline",
        default="inprocess",
        metavar="NAME",
        help="inprocess (default: the lockstep loop in one process), distributed (the four "
        "service processes, own key prefix per run), or module:function",
    )
    where = p.add_mutually_exclusive_group()  # one executor or the other
    # No default here: argparse takes an option given at its default value for not given.
    where.add_argument("--jobs", type=int, default=None, help="local worker processes (default 2)")
    where.add_argument(
        "--cluster",
        default=None,
        metavar="ADDRESS|local:N",
        help="run on a Dask distributed cluster (scheduler address, or local:N worker "
        "processes) instead of --jobs; needs the 'cluster' extra",
    )
    p.add_argument(
        "--resume", action="store_true", help="keep the runs already in --out's runs.jsonl"
    )
    p.add_argument(
        "--record-failures",
        action="store_true",
        help="afterwards, re-run each strategy's first failure of each cause with the "
        "distributed pipeline and record it (MCAP without the camera frames, for umay plot)",
    )
    p.add_argument(
        "--record-frames",
        action="store_true",
        help="with --record-failures: keep the camera frames in the recordings (megabytes each)",
    )
    p.add_argument("--out", default="out/domains", metavar="DIR", help="output folder")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")
    p.set_defaults(func=cmd_domains)


DEFAULT_JOBS = 2


def parse_cells(text: str | None, n: int) -> range:
    if text is None:
        return range(n)
    a, sep, b = text.partition(":")
    try:
        lo, hi = int(a or 0), int(b or n) if sep else int(a) + 1
    except ValueError as exc:
        raise ValueError(f"--cells: {text!r}: A:B, cell indices") from exc
    if lo >= hi:
        raise ValueError(f"--cells: {text!r}: A below B (cells A to B-1)")
    if not 0 <= lo < hi <= n:
        raise ValueError(f"--cells: {text!r}: within 0:{n}")
    return range(lo, hi)


# Next to runs.jsonl: the study its runs belong to, so that --resume never keeps the runs of
# another (the runs are keyed by cell, draw and strategy only: another seed draws other starts
# under the same keys).
STUDY_OF_RUNS = "runs.study.json"
REPORT_ONLY = frozenset({"success_goal"})  # fields of a study that change no run


def study_note(study: StudyDefinition, sets: list[str]) -> dict:
    """What :data:`STUDY_OF_RUNS` holds: the study's definition and the ``--set`` items."""
    return {"study": study.model_dump(mode="json"), "set": list(sets)}


def resume_refusal(out_dir: Path, study: StudyDefinition, sets: list[str]) -> str:
    """Why ``--resume`` cannot keep the runs in ``out_dir`` for ``study`` with ``--set``
    ``sets`` ("" when it can): they were made for another definition or other overrides."""
    from deploy.experiments.domains.report import load_study_json

    here = study_note(study, sets)
    sidecar = out_dir / STUDY_OF_RUNS
    if sidecar.is_file():
        there = json.loads(sidecar.read_text())
    elif (out_dir / "domains.json").is_file():  # published without its note: no --set to check
        kept = load_study_json(out_dir / "domains.json")
        there = study_note(kept.study, sets)
    else:
        return ""  # nothing kept, or runs written before studies were noted: taken as the same
    differ = [
        f"{name} {there['study'].get(name)!r} there, {here['study'].get(name)!r} here"
        for name in here["study"]
        if name not in REPORT_ONLY and there["study"].get(name) != here["study"].get(name)
    ]
    if there.get("set") != here["set"]:
        differ.append(f"--set {there.get('set')} there, {here['set']} here")
    if not differ:
        return ""
    return (
        f"--resume: the runs in {out_dir} belong to another study ({'; '.join(differ)}); "
        "resume with the same study, seed, draws and --set, or choose another --out"
    )


def kept_runs(data: bytes, name: str) -> tuple[list[DomainRecord], str]:
    """The runs of a ``runs.jsonl`` (``data``, the file ``name``) for ``--resume``, and a
    warning ("" when none). Its last line may have been cut off (a study killed while writing
    it): it is dropped with the warning, and its run is done again. A bad line before it is not
    that: a :class:`ValueError` naming the file and the line."""
    from pydantic import ValidationError

    from deploy.experiments.domains.study import DomainRecord

    # Bytes: a cut may split a character, and a line break is b"\n" only (str.splitlines
    # would also break at U+2028, which JSON leaves as it is inside a string).
    lines = data.splitlines()
    runs: list[DomainRecord] = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            runs.append(DomainRecord.model_validate_json(line))
        except ValidationError as exc:
            reason = exc.errors()[0]["msg"]
            if number < len(lines):
                raise ValueError(f"--resume: {name} line {number}: not a run ({reason})") from exc
            return runs, f"{name} line {number}: cut off ({reason}); that run is done again"
    return runs, ""


def cmd_domains(args: argparse.Namespace) -> int:
    """Exit 0 when the study completed (whatever its runs' outcomes), 2 on bad input, 130
    when interrupted (the finished runs are written)."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from deploy.experiments.compare import CompareError
    from deploy.experiments.compare.plan import check_jobs, parse_modes
    from deploy.experiments.domains import study as dom
    from deploy.experiments.domains.run import (
        ExecutorError,
        check_cluster,
        draw_one,
        execute,
        gather,
        make_executor,
        resolve_runner,
    )
    from deploy.paths import OutputPathError, check_output_dir

    console = progress_console()
    try:
        modes = parse_modes(args.modes)
        args.jobs = DEFAULT_JOBS if args.jobs is None else args.jobs
        check_jobs(args.jobs)
        study, base_path = dom.load_study(Path(args.study), seed=args.seed, draws=args.draws)
        chosen = parse_cells(args.cells, study.n_cells)
        if args.pipeline not in ("inprocess", "distributed"):
            resolve_runner(args.pipeline)
        check_cluster(args.cluster)  # before --out is made
        dom.check_overrides(study, base_path, modes, args.set)  # else a worker raises it
        out_dir = check_output_dir("--out", args.out)
        refusal = resume_refusal(out_dir, study, args.set) if args.resume else ""
        if refusal:
            raise ValueError(refusal)
        jsonl = out_dir / "runs.jsonl"
        logged = jsonl.read_bytes() if args.resume and jsonl.is_file() else None
        kept, warning = kept_runs(logged, str(jsonl)) if logged is not None else ([], "")
        executor = make_executor(args.jobs, args.cluster)
    except (CompareError, OutputPathError, ExecutorError, ValueError) as exc:
        print(f"umay domains: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if warning:
        print(f"umay domains: warning: {warning}", file=sys.stderr)

    columns = (
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
    )
    started = time.monotonic()
    # Ctrl-C and SIGTERM: the runs stop; those finished are kept in runs.jsonl.
    with stop_requested() as stop, contextlib.closing(executor):
        cells = [c for c in dom.cells(study) if c.index in chosen]
        items = [
            (study, str(base_path), c, d, tuple(args.set))
            for c in cells
            for d in range(study.draws)
        ]
        with progress_bar(console, *columns) as bar:
            task = bar.add_task("drawing starts", total=len(items))
            drawn = gather(executor, draw_one, items, stop, lambda _i, _v: bar.advance(task))
        starts = [drawn[i] for i in sorted(drawn)]
        try:
            tasks = dom.plan_tasks(study, base_path, starts, modes, args.set)
        except CompareError as exc:  # what check_overrides could not see: a start's own
            print(f"umay domains: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
        done: dict[str, dom.DomainRecord] = {}
        earlier_wall_s = 0.0
        published = out_dir / "domains.json"
        if logged is not None:
            done = {rec.key: rec for rec in kept}
            if warning or not logged.endswith(b"\n"):
                # What is appended next must start a line of its own, not end the cut one.
                jsonl.write_text("".join(rec.model_dump_json() + "\n" for rec in kept))
        elif args.resume and published.is_file():
            # A published study keeps domains.json, not the log it was built from.
            from deploy.experiments.domains.report import load_study_json

            kept = load_study_json(published)
            done = {rec.key: rec for rec in kept.runs}
            earlier_wall_s = kept.wall_time_s  # the study's time is its runs' time
            jsonl.write_text("".join(rec.model_dump_json() + "\n" for rec in done.values()))
        else:
            jsonl.write_text("")
        note = json.dumps(study_note(study, args.set), indent=1)
        (out_dir / STUDY_OF_RUNS).write_text(note + "\n")
        todo = [t for t in tasks if t.key not in done]
        refused = sum(bool(s.refused) for s in starts)
        console.print(
            f"{len(starts)} starts ({len(cells)} cells × {study.draws} draws, seed {study.seed}), "
            f"{refused} refused at start; {len(tasks)} runs ({len(done)} kept from runs.jsonl), "
            f"{args.pipeline} pipeline, {executor.name}"
        )
        counts = {"converged": 0, "failed": 0}
        with progress_bar(console, *columns) as bar, jsonl.open("a") as sink:
            progress = bar.add_task("runs", total=len(todo))

            def on_done(_i: int, rec: dom.DomainRecord) -> None:
                done[rec.key] = rec
                sink.write(rec.model_dump_json() + "\n")
                sink.flush()  # a crash or Ctrl-C keeps every finished run
                counts[rec.outcome] += 1
                bar.update(
                    progress,
                    advance=1,
                    description=f"{counts['converged']} converged, {counts['failed']} failed",
                )

            if not stop.is_set():
                gather(executor, execute, [(t, args.pipeline) for t in todo], stop, on_done)
    wall_s = earlier_wall_s + time.monotonic() - started
    order = {t.key: i for i, t in enumerate(tasks)}
    runs = sorted((r for r in done.values() if r.key in order), key=lambda r: order[r.key])
    by_key = {t.key: t for t in tasks}
    return finish(
        args, study, modes, starts, by_key, runs, executor.name, wall_s, stop.is_set(), out_dir
    )


def finish(
    args, study, modes, starts, tasks, runs, executor_name, wall_s, interrupted, out_dir
) -> int:
    from deploy.experiments.domains.report import (
        Study,
        report_markdown,
        representative_failures,
        write_heatmaps,
    )

    result = Study(
        study=study,
        study_file=Path(args.study).name,
        modes=list(modes),
        pipeline=args.pipeline,
        executor=executor_name,
        wall_time_s=wall_s,
        complete=not interrupted,
        starts=list(starts),
        runs=runs,
    )
    (out_dir / "domains.json").write_text(json.dumps(result.model_dump(), indent=1) + "\n")
    figures = write_heatmaps(result, out_dir) if runs else []
    recordings: dict[str, str] = {}
    if args.record_failures and not interrupted:
        recordings = record_failures(
            representative_failures(result), tasks, out_dir, frames=args.record_frames
        )
    relative = [str(p.relative_to(out_dir)) for p in figures]
    (out_dir / "report.md").write_text(report_markdown(result, relative, recordings))
    per_run = wall_s / len(runs) if runs else 0.0
    print(
        f"{len(runs)} runs in {wall_s / 60:.1f} min ({per_run:.2f} s wall a run, "
        f"{executor_name}); {out_dir / 'report.md'}",
        file=sys.stderr,
    )
    return EXIT_INTERRUPTED if interrupted else EXIT_OK


def record_failures(failures, tasks, out_dir: Path, frames: bool = False) -> dict[str, str]:
    """Each failure re-run in the distributed lockstep pipeline and recorded (MCAP; the camera
    frames only if ``frames``): lockstep runs repeat, so the recording shows the failure the
    study counted; paths relative to ``out_dir``."""
    import tempfile

    from common.session import free_tcp_endpoint
    from deploy.launch.run import run_once

    out: dict[str, str] = {}
    for rec in failures:
        task = tasks[rec.key]
        path = out_dir / "recordings" / f"{rec.key}.mcap"
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix="umay-domains-") as logs:
            run_once(
                task.scenario_path, task.scenario(), list(task.overrides),
                prefix=f"umay/domains-record/{rec.key}", log_dir=Path(logs),
                listen=free_tcp_endpoint(), quiet=True, record=path, record_frames=frames,
            )  # fmt: skip
        out[rec.key] = str(path.relative_to(out_dir))
    return out
