"""``umay bench`` on the command line: its parser and handler, apart from the bench's modules
so that building the ``umay`` parser imports nothing heavy."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from common.config import ClockMode, Scenario, ScenarioError
from deploy.arguments import at_least_one
from deploy.exit_codes import EXIT_BAD_INPUT
from deploy.paths import FIGURE_SUFFIXES, check_output_dir, check_output_file

DEFAULT_PAIRS = 3  # pairs of runs of --alternate

if TYPE_CHECKING:
    from deploy.bench.report import BenchReport


def cmd_bench(args: argparse.Namespace) -> int:
    from deploy.bench import BenchError
    from deploy.bench.report import median_of_runs, write_json
    from deploy.bench.text import format_report
    from deploy.launch.run import prepare

    if args.workflows:
        return workflows(args)
    size = args.size.lower().split("x")
    if len(size) != 2 or not all(p.isdigit() for p in size):
        print(f"umay bench: --size {args.size!r}: expected WxH, e.g. 640x480", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.mode not in {c.value for c in ClockMode}:
        print(f"umay bench: --mode {args.mode!r}: lockstep or realtime", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.frames < 2 or args.warmup < 0 or (args.synthetic_frames or 0) < 0 or args.repeat < 1:
        print(
            "umay bench: --frames >= 2, --repeat >= 1, --warmup and --synthetic-frames >= 0",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    if args.pairs is not None and args.alternate is None:
        print("umay bench: --pairs counts the pairs of --alternate: give it too", file=sys.stderr)
        return EXIT_BAD_INPUT
    args.pairs = DEFAULT_PAIRS if args.pairs is None else args.pairs
    if args.alternate is not None and (args.figure or args.view):
        print(
            "umay bench: --alternate compares headline figures: no --figure or --view with it",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    overrides = [
        f"camera.width_px={size[0]}",
        f"camera.height_px={size[1]}",
        f"run.clock='{args.mode}'",
        *args.set,
    ]
    try:
        scenario = prepare(args.scenario, overrides)
        changed = None  # the changed side of --alternate, checked before anything runs
        if args.alternate is not None:
            changed = prepare(args.scenario, [*overrides, args.alternate])
    except ScenarioError as exc:
        print(f"umay bench: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.json:
        check_output_file("--json", args.json)
    if args.figure:
        check_output_file("--figure", args.figure, FIGURE_SUFFIXES)
    check_output_dir("--log-dir", args.log_dir)
    if changed is not None:
        return alternate(args, scenario, changed, overrides)
    try:
        runs = repeated_runs(args, scenario, overrides)
    except BenchError as exc:
        print(f"umay bench: {exc}", file=sys.stderr)
        return 1
    result = runs[0] if len(runs) == 1 else median_of_runs(runs)
    print(format_report(result))

    def write() -> None:
        if args.json:
            write_json(result, args.json)
        if args.figure:
            from deploy.bench.figure import write_bench_figure

            # frame by frame: the first run
            write_bench_figure(runs[0].to_json(), Path(args.figure))
            print(f"figure: {args.figure}" + (" (the first run)" if len(runs) > 1 else ""))

    return written(write)


def written(write: Callable[[], object]) -> int:
    """The exit code of writing the results: 1, said, when the disk refuses. The paths were
    checked before the runs; this fails only if the disk changed since (full, say)."""
    try:
        write()
    except OSError as exc:
        print(f"umay bench: could not write the results: {exc}", file=sys.stderr)
        return 1
    return 0


def repeated_runs(
    args: argparse.Namespace,
    scenario: Scenario,
    overrides: list[str],
    label: str = "",
    print_each: bool = True,
) -> list[BenchReport]:
    """``--repeat`` benchmark runs of ``scenario``, each printed when there are several
    (and ``print_each``). Raises BenchError."""
    from deploy.bench.run import run_bench
    from deploy.bench.text import format_report

    runs = []
    for i in range(args.repeat):
        result = run_bench(
            args.scenario,
            scenario,
            overrides,
            args.frames,
            args.warmup,
            Path(args.log_dir),
            shm=not args.no_shm,
            synthetic_frames=args.synthetic_frames,
            command=typed_command(),
            reference_renderer=not args.no_reference,
            view=args.view,
            on_phase=say_phase(i, args.repeat, label),
        )
        runs.append(result)
        if args.repeat > 1 and print_each:
            print(f"--- {label}run {i + 1} of {args.repeat}\n{format_report(result)}\n", flush=True)
    return runs


def alternate(
    args: argparse.Namespace, scenario: Scenario, changed: Scenario, overrides: list[str]
) -> int:
    """``--pairs`` pairs of the bench: ``scenario`` without, then ``changed`` with
    ``--alternate``'s change."""
    from deploy.bench import BenchError
    from deploy.bench.alternate import (
        AlternationReport,
        Pair,
        format_alternation,
        format_side,
        side_figures,
        write_alternation,
    )
    from deploy.bench.report import median_of_runs

    changed_overrides = [*overrides, args.alternate]
    pairs: list[Pair] = []
    machine = None
    try:
        for i in range(args.pairs):
            sides = []
            for label, sc, ov in (
                ("without", scenario, overrides),
                (f"with {args.alternate}", changed, changed_overrides),
            ):
                which = f"pair {i + 1} of {args.pairs}, {label}"
                runs = repeated_runs(args, sc, ov, f"{which}: ", print_each=False)
                report = runs[0] if len(runs) == 1 else median_of_runs(runs)
                machine = machine or report.machine
                sides.append(side_figures(report))
                print(f"{which}: {format_side(sides[-1])}", flush=True)
            pairs.append(Pair(without=sides[0], with_change=sides[1]))
    except BenchError as exc:
        print(f"umay bench: {exc}", file=sys.stderr)
        return 1
    assert machine is not None  # --pairs >= 1
    report = AlternationReport(
        command=typed_command(),
        change=args.alternate,
        machine=machine,
        pairs=pairs,
    )
    print(format_alternation(report))
    return written(lambda: args.json and write_alternation(report, args.json))


def workflows(args: argparse.Namespace) -> int:
    """``--workflows``: ``make run``, ``umay compare`` and ``make test`` timed on fresh clones
    (:mod:`deploy.bench.workflows`); the loop's own options do not apply."""
    from deploy.bench import BenchError
    from deploy.bench.processes import code_version
    from deploy.bench.workflows import format_workflows, run_workflows, write_workflows

    loop_only = {
        "--alternate": args.alternate is not None,
        "--figure": bool(args.figure),
        "--view": args.view,
        "--scenario": args.scenario is not None,
        "--set": bool(args.set),
        "--no-shm": args.no_shm,
    }
    given = [name for name, on in loop_only.items() if on]
    if given:
        print(
            f"umay bench: --workflows times commands on fresh clones; {', '.join(given)} "
            "apply to the loop's bench only",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    if args.json:
        check_output_file("--json", args.json)
    log_dir = check_output_dir("--log-dir", args.log_dir)
    if (code_version() or "").endswith("-dirty"):
        print(
            "umay bench: the checkout has uncommitted changes; the clones hold its last commit",
            file=sys.stderr,
        )
    say = say_phase(0, 1, "workflows: ")
    try:
        report = run_workflows(Path(log_dir) / "workflows", typed_command(), on_step=say)
    except BenchError as exc:
        print(f"umay bench: {exc}", file=sys.stderr)
        return 1
    print(format_workflows(report))
    return written(lambda: args.json and write_workflows(report, args.json))


def typed_command() -> str:
    """The command as the user typed it, for the reports (each JSON says what made it)."""
    return " ".join(["umay", *sys.argv[1:]])


def say_phase(run: int, runs: int, label: str = "") -> Callable[[str], None]:
    """Progress on standard error: which part of which run (of which pair) starts."""
    which = label + (f"run {run + 1} of {runs}: " if runs > 1 else "")
    return lambda what: print(f"umay bench: {which}{what}", file=sys.stderr, flush=True)


def add_bench_parser(sub: argparse._SubParsersAction) -> None:
    """``umay bench``: the loop's latency and throughput."""
    p = sub.add_parser(
        "bench",
        help="loop latency and throughput per stage, vs in-process",
        description="Run the four services and split every camera frame's way round the loop "
        "into stages, against the same functions in one process; also the render and Kinect "
        "model cost, the loop with TinyRenderer, and a 30 Hz source (docs/performance.md).",
    )
    p.add_argument("--frames", type=int, default=100, help="measured frames (after warm-up)")
    p.add_argument("--warmup", type=int, default=5, help="frames left out at the start")
    p.add_argument("--size", default="640x480", help="colour image WxH (default 640x480)")
    p.add_argument("--mode", default="lockstep", help="clock: lockstep|realtime")
    p.add_argument(
        "--no-shm",
        action="store_true",
        help="shared memory off everywhere: camera frames whole, by copy, not by reference",
    )
    p.add_argument(
        "--no-reference",
        action="store_true",
        help="skip the TinyRenderer reference (its render cost and its loop)",
    )
    p.add_argument("--repeat", type=int, default=1, help="runs; the table shows their medians")
    p.add_argument(
        "--view",
        action="store_true",
        help="with a live view (umay view) and a Foxglove client connected during the loop",
    )
    p.add_argument(
        "--synthetic-frames",
        type=int,
        default=None,
        help="frames of the 30 Hz synthetic source (default: --frames; 0: skip it)",
    )
    p.add_argument("--json", default=None, metavar="OUT.json", help="write the results here")
    p.add_argument(
        "--figure",
        default=None,
        metavar="OUT.png",
        help="the frames' stages as a figure, .png, .svg or .pdf (1st run)",
    )
    p.add_argument("--scenario", default=None, help="scenario TOML (default: default.toml)")
    p.add_argument("--log-dir", default="out/logs/bench", help="the services' log files")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")
    p.add_argument(
        "--alternate",
        default=None,
        metavar="TABLE.FIELD=VALUE",
        help="judge one change: run the bench without and with this --set item in turns "
        "(--pairs pairs) and compare their headline figures; --json writes the pairs",
    )
    p.add_argument(
        "--pairs",
        type=at_least_one,
        default=None,
        help=f"pairs of runs with --alternate ({DEFAULT_PAIRS})",
    )
    p.add_argument(
        "--workflows",
        action="store_true",
        help="instead of the loop: time `make run` (fresh, then installed), `umay compare "
        "--jobs 2` and `make test` on fresh clones of this checkout's commit (minutes)",
    )
    p.set_defaults(func=cmd_bench)


# Command name -> what adds its parser; deploy.cli puts them in the help's order.
COMMANDS: dict[str, Callable[[argparse._SubParsersAction], None]] = {
    "bench": add_bench_parser,
}
