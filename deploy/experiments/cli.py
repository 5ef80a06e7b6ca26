"""``umay compare`` on the command line: parse, validate (exit 2, nothing launched), run with a
progress bar, write the outputs; ``umay campaign`` and ``umay accuracy`` likewise. Kept apart
from :mod:`deploy.experiments.compare` so that building the ``umay`` parser imports nothing
heavy."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from common.config import ScenarioError
from deploy.arguments import a_seed, at_least_one
from deploy.consoles import progress_bar, progress_console
from deploy.exit_codes import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK
from deploy.experiments.compare import ALL_MODES
from deploy.experiments.domains.cli import add_domains_parser
from deploy.interrupts import stop_requested
from deploy.paths import check_output_file

if TYPE_CHECKING:
    from rich.console import Console

    from deploy.experiments.compare.plan import Plan

DEFAULT_SCENARIO_DIR = Path(__file__).resolve().parents[1] / "scenarios" / "suite"
# Relative difference allowed by default between float results and --reference's: lockstep runs
# repeat bit for bit on one machine, but another CPU's BLAS/LAPACK kernels round the last bits
# differently and a hundred frames of closed loop carry that into later digits (1.9e-5 at most
# on an AVX-512 CPU against results made on one without). Counts, flags and reasons must match
# exactly whatever the tolerance.
REFERENCE_REL_TOL = 1e-4


# --- command line --------------------------------------------------------------------------
def _pipeline_option(p: argparse.ArgumentParser) -> None:
    """``--pipeline`` of compare and campaign (:func:`deploy.experiments.compare.run.run_all`)."""
    p.add_argument(
        "--pipeline",
        choices=("distributed", "inprocess"),
        default="distributed",
        help="distributed (default: the four service processes a run) or inprocess (the same "
        "lockstep loop in one worker process a run, the same results; the figures scenario's "
        "runs still distributed, for their recordings)",
    )


def add_compare_parser(sub: argparse._SubParsersAction) -> None:
    """The ``compare`` subcommand, for :func:`deploy.cli.build_parser`."""
    p = sub.add_parser(
        "compare",
        help="every strategy on every scenario of a suite: results, summary, figures",
        description="Run every strategy on every scenario of a folder (default: the suite, "
        "deploy/scenarios/suite) and write results.csv/.json, summary.md and the figures "
        "(docs/results.md). --pipeline inprocess runs each in one worker process: the same "
        "results to the bit, a few times faster. Exit 0 done, 1 a --reference differs, 2 bad "
        "input (nothing run), 130 interrupted.",
    )
    p.add_argument(
        "--scenarios",
        default=str(DEFAULT_SCENARIO_DIR),
        metavar="DIR",
        help="folder of scenario TOML files (default: deploy/scenarios/suite)",
    )
    p.add_argument(
        "--modes",
        nargs="+",
        default=None,
        metavar="MODE",
        help=f"strategies (default: all: {' '.join(ALL_MODES)})",
    )
    p.add_argument("--jobs", type=int, default=2, help="runs at once (default 2)")
    _pipeline_option(p)
    p.add_argument("--out", default="out/compare", metavar="DIR", help="output folder")
    p.add_argument(
        "--figures-scenario",
        default=None,
        metavar="NAME",
        help="scenario whose runs are recorded and plotted (default: the first)",
    )
    p.add_argument(
        "--reference",
        default=None,
        metavar="RESULTS.json",
        help="a previous comparison's results.json: exit 1 if a number of any run of this "
        "comparison differs from it (wall time aside; its other runs are ignored)",
    )
    p.add_argument(
        "--tolerance",
        type=float,
        default=REFERENCE_REL_TOL,
        metavar="REL",
        help=f"with --reference: relative difference allowed between float results (default "
        f"{REFERENCE_REL_TOL:g}: another CPU rounds the last bits differently); 0 = bit-identical",
    )
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")
    p.set_defaults(func=cmd_compare)


def cmd_compare(args: argparse.Namespace) -> int:
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from common.config import ScenarioError
    from deploy.experiments.compare import CompareError
    from deploy.experiments.compare.plan import Job, check_jobs, parse_modes, plan
    from deploy.experiments.compare.rows import CompareRow, check_against, rows_from_json
    from deploy.experiments.compare.run import job_label, run_all, write_outputs
    from deploy.markdown import format_cell
    from deploy.paths import OutputPathError, check_output_dir

    console = progress_console()

    def bad(message: str) -> int:
        print(f"umay compare: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT

    try:
        modes = parse_modes(args.modes)
        check_jobs(args.jobs)
        if not 0.0 <= args.tolerance < 1.0:  # also refuses nan
            raise CompareError(
                f"--tolerance: a relative difference in [0, 1), not {args.tolerance}"
            )
        reference = None
        if args.reference:
            try:
                reference = rows_from_json(Path(args.reference).read_text())
            except (OSError, ValueError) as exc:
                raise CompareError(f"--reference: {args.reference}: {exc}") from exc
        the_plan = plan(Path(args.scenarios), modes, args.set, args.figures_scenario)
        out_dir = check_output_dir("--out", args.out)  # last: nothing is created on bad input
    except (CompareError, ScenarioError, OutputPathError) as exc:
        return bad(str(exc))

    started = time.monotonic()
    columns = (
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
    )
    rows: list[CompareRow] = []
    running: set[str] = set()
    # Ctrl-C and SIGTERM: the running pipelines are stopped, nothing is left behind.
    with stop_requested() as stop, progress_bar(console, *columns) as bar:
        task = bar.add_task("compare", total=len(the_plan.jobs))

        def on_start(job: Job) -> None:
            running.add(job_label(job))
            bar.update(task, description=", ".join(sorted(running)))

        def on_done(job: Job, row: CompareRow) -> None:
            running.discard(job_label(job))
            outcome = f"{row.reason:>9s}"  # padded before colouring: markup has no width
            colour = "green" if row.converged else "red"
            bar.console.print(
                f"{job_label(job):34s} [{colour}]{outcome}[/] {row.frames:4d} frames "
                f"{format_cell(row.final_pixel_rms):>6s} px "
                f"{format_cell(row.final_position_error_m, 1000.0, '.2f'):>6s} mm "
                f"ratio {format_cell(row.path_ratio)} {row.wall_time_s:5.1f} s"
            )
            bar.update(task, advance=1, description=", ".join(sorted(running)) or "done")

        rows = run_all(the_plan.jobs, args.jobs, out_dir, stop, on_start, on_done, args.pipeline)
        interrupted = stop.is_set()
    wall_s = time.monotonic() - started
    if interrupted:
        console.print(
            f"[red]interrupted[/]: every pipeline stopped; the results, summary, figures and "
            f"their recordings in {out_dir} left as they were (an interrupted comparison writes "
            "none; logs/ has its runs' logs)"
        )
        return EXIT_INTERRUPTED
    figures = draw_figures(the_plan, out_dir, console)
    note = f"Wall time {wall_s / 60:.1f} min with {args.jobs} job(s) at once."
    for path in write_outputs(the_plan, rows, out_dir, figures, note):
        print(path)
    for path in figures:
        print(path)
    converged = sum(r.converged for r in rows)
    console.print(f"{converged}/{len(rows)} runs converged in {wall_s / 60:.1f} min")
    if reference is not None:
        same, lines = check_against(reference, rows, args.reference, args.tolerance)
        console.print(lines[0] if same else f"[red]{lines[0]}[/]", *lines[1:], sep="\n")
        return EXIT_OK if same else EXIT_FAILED
    return EXIT_OK


def draw_figures(plan_: Plan, out_dir: Path, console: Console) -> list[Path]:
    """The comparison's figures (:func:`~deploy.experiments.compare.run.make_figures`) with a
    progress bar: after the runs they take a second or two per strategy."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

    from deploy.experiments.compare.run import make_figures

    if not any(job.record for job in plan_.jobs):
        return []
    columns = (
        TextColumn("[bold]figures"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()
    )  # fmt: skip
    with progress_bar(console, *columns, transient=True) as bar:
        task = bar.add_task("figures", total=len(plan_.modes) + 1)  # and the overlay
        return make_figures(plan_, out_dir, lambda _name: bar.advance(task))


# --- umay campaign ---------------------------------------------------------------------------
def add_campaign_parser(sub: argparse._SubParsersAction) -> None:
    """The ``campaign`` subcommand: random starts, every strategy, a failure taxonomy."""
    from deploy.experiments.campaign.starts import DEFAULT_DISTRIBUTION

    p = sub.add_parser(
        "campaign",
        help="every strategy from N random starts: results, summary, failure taxonomy",
        description="Draw N starts from the distribution in deploy/campaigns/random_starts.toml "
        "(seeded: the same seed gives the same campaign, bit for bit), run every strategy "
        "from each, and write compare's outputs plus campaign.md, causes.json and starts.json: "
        "one named cause per run that did not end on its goal (docs/campaign.md).",
    )
    which = p.add_mutually_exclusive_group()
    which.add_argument("--n", type=int, default=20, help="starts to draw (default 20)")
    which.add_argument(
        "--only",
        nargs="+",
        default=[],
        metavar="START",
        help="only these starts, instead of the first N: their names in campaign.md (e.g. "
        "start_0003) or indices; the same starts as in the whole campaign, to see some of its "
        "runs again (with figures, the first one's runs are recorded and plotted)",
    )
    p.add_argument(
        "--seed", type=a_seed, default=None, help="instead of the distribution file's seed"
    )
    p.add_argument(
        "--distribution",
        default=str(DEFAULT_DISTRIBUTION),
        metavar="FILE.toml",
        help="the start distribution (default: deploy/campaigns/random_starts.toml)",
    )
    p.add_argument("--modes", nargs="+", default=None, metavar="MODE", help="strategies")
    p.add_argument("--jobs", type=int, default=2, help="runs at once (default 2)")
    _pipeline_option(p)
    p.add_argument("--out", default="out/campaign", metavar="DIR", help="output folder")
    p.add_argument(
        "--no-figures",
        action="store_true",
        help="no figures: the first start's runs are not recorded (with --pipeline inprocess, "
        "every run then stays in-process)",
    )
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")
    p.set_defaults(func=cmd_campaign)


def cmd_campaign(args: argparse.Namespace) -> int:
    """Exit 0 when every run has a named cause (whatever it is), 2 on bad input, 130 when
    interrupted."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

    from deploy.experiments.campaign.causes import failure_cause
    from deploy.experiments.campaign.run import (
        campaign_inputs,
        parse_only,
        plan_campaign,
        run_campaign,
        write_campaign,
    )
    from deploy.experiments.compare import CompareError
    from deploy.experiments.compare.plan import Job, check_jobs, parse_modes
    from deploy.experiments.compare.rows import CompareRow
    from deploy.markdown import format_cell
    from deploy.paths import OutputPathError, check_output_dir

    console = progress_console()
    try:
        modes = parse_modes(args.modes)
        check_jobs(args.jobs)
        # Every input checked, --out last (it creates the folder), before minutes of drawing.
        only = parse_only(args.only)
        campaign_inputs(args.n, Path(args.distribution), args.seed, args.set)
        out_dir = check_output_dir("--out", args.out)
        columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn())
        with progress_bar(console, *columns, TimeElapsedColumn(), transient=True) as bar:
            drawing = bar.add_task("drawing starts", total=len(only) or args.n)
            cplan = plan_campaign(
                args.n, modes, Path(args.distribution), args.seed, args.set,
                not args.no_figures, args.jobs, lambda _i: bar.advance(drawing), only,
            )  # fmt: skip
    except (CompareError, OutputPathError) as exc:
        print(f"umay campaign: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    refused = [s for s in cplan.starts if s.refused]
    console.print(
        f"{len(cplan.starts)} starts (seed {cplan.distribution.seed}), {len(refused)} refused "
        f"at start; {len(cplan.plan.jobs)} runs"
    )
    for s in refused:
        console.print(f"{s.name} refused: {s.refused}")
    started = time.monotonic()
    done = [0]

    def on_done(job: Job, row: CompareRow) -> None:
        done[0] += 1
        console.print(
            f"[{done[0]}/{len(cplan.plan.jobs)}] {row.scenario} · {row.mode:8s} "
            f"{failure_cause(row):28s} {row.frames:4d} frames "
            f"{format_cell(row.final_position_error_m, 1000.0, '.2f'):>7s} mm "
            f"{row.wall_time_s:5.1f} s"
        )

    # Ctrl-C and SIGTERM: the running pipelines are stopped, nothing is written.
    with stop_requested() as stop:
        rows = run_campaign(
            cplan, args.jobs, out_dir, stop, lambda _job: None, on_done, args.pipeline
        )
    if stop.is_set():
        console.print("[red]interrupted[/]: every pipeline stopped; nothing written")
        return EXIT_INTERRUPTED
    wall_s = time.monotonic() - started
    figures = draw_figures(cplan.plan, out_dir, console) if rows else []
    note = (
        f"Random-start campaign: {len(cplan.starts)} starts, seed {cplan.distribution.seed}; "
        f"wall time {wall_s / 60:.1f} min with {args.jobs} job(s) at once."
    )
    for path in write_campaign(cplan, rows, out_dir, figures, note):
        print(path)
    return EXIT_OK


def cmd_accuracy(args: argparse.Namespace) -> int:
    from common.config import load_scenario
    from common.runtime import parse_overrides
    from deploy.launch.reachability import check_scenario

    try:
        overrides = parse_overrides(args.set)
        scenarios = [load_scenario(p, overrides) for p in (args.scenario or [None])]
        for scenario in scenarios:  # what `umay run` refuses (a target out of view, ...)
            check_scenario(scenario)
    except ScenarioError as exc:
        print(f"umay accuracy: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.json:
        check_output_file("--json", args.json)
    # Imported only now: it loads pybullet.
    from deploy.experiments.accuracy import default_conditions, evaluate, format_table

    conditions = default_conditions(args.seed)
    with progress_bar(progress_console(), transient=True) as bar:
        task = bar.add_task("postures", total=args.frames * len(scenarios))
        results = evaluate(
            scenarios,
            args.frames,
            conditions,
            args.seed,
            progress=lambda done, _total: bar.update(task, completed=done),
        )
    print(format_table(results))
    if args.json:
        Path(args.json).write_text(json.dumps([r.model_dump() for r in results], indent=2) + "\n")
    return 0


def add_accuracy_parser(sub: argparse._SubParsersAction) -> None:
    """``umay accuracy``: vision against the simulator's truth."""
    p = sub.add_parser("accuracy", help="vision against ground truth under sensor conditions")
    p.add_argument("--scenario", action="append", default=None, help="scenario TOML (repeatable)")
    p.add_argument("--frames", type=at_least_one, default=100, help="postures per scenario")
    p.add_argument("--seed", type=a_seed, default=0, help="the postures' and noise's seed (0)")
    p.add_argument("--json", default=None, metavar="OUT.json", help="write the results here")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")
    p.set_defaults(func=cmd_accuracy)


# Command name -> what adds its parser; deploy.cli puts them in the help's order.
COMMANDS: dict[str, Callable[[argparse._SubParsersAction], None]] = {
    "accuracy": add_accuracy_parser,
    "compare": add_compare_parser,
    "campaign": add_campaign_parser,
    "domains": add_domains_parser,
}
