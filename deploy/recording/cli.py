"""The recording commands of ``umay``: record, info, replay and plot (their parsers
and handlers; :mod:`deploy.cli` puts them together)."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path

import zenoh

from common.config import ScenarioError, load_scenario
from common.keys import PREFIX_HELP, Keys, default_prefix
from common.runtime import endpoints_argument, parse_overrides, prefix_argument
from common.session import open_session, where_connecting, zenoh_reason
from deploy.arguments import NOTHING_RUNNING_THERE, positive_seconds
from deploy.exit_codes import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_NOT_CONVERGED
from deploy.interrupts import stop_requested
from deploy.paths import check_output_dir, check_output_file, remove_created_folders


def cmd_record(args: argparse.Namespace) -> int:

    from deploy.recording.record import Recorder, run_metadata

    if args.keys is not None:
        try:
            zenoh.KeyExpr(args.keys)
        except zenoh.ZError as exc:
            print(f"umay record: --keys {args.keys!r}: {zenoh_reason(exc)}", file=sys.stderr)
            return EXIT_BAD_INPUT
    check_output_file("OUT.mcap", args.out)
    keys = Keys(args.prefix or default_prefix())
    metadata = {"prefix": keys.prefix, "recorded_by": "umay record"}
    if args.scenario or args.set:
        try:  # the scenario a replay will start services with: valid, or refused by name
            load_scenario(args.scenario, parse_overrides(args.set))
            metadata = run_metadata(args.scenario, args.set, keys.prefix)
        except ScenarioError as exc:
            print(f"umay record: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
    with stop_requested() as stop:
        session = open_session(connect=args.connect)
        try:
            with Recorder(args.out, session, keys, args.keys, metadata) as recorder:
                what = f"{recorder.key_expr} to {args.out}"
                print(f"recording {what} (Ctrl-C to stop)", file=sys.stderr)
                stop.wait(args.duration)
            counts = recorder.message_counts()
        finally:
            session.close()
    total = sum(counts.values())
    if total:
        for key, n in sorted(counts.items()):
            print(f"{n:8d}  {key}")
        print(f"{total:8d}  messages in {args.out}")
    if recorder.lost:
        print(f"{recorder.lost:8d}  frames lost (last: {recorder.last_loss})")
    if not total:  # the recorder made no file (nor emptied one there): no folder either
        remove_created_folders()
        where = where_connecting(args.connect)
        print(
            f"umay record: nothing heard on {recorder.key_expr} at {where}, so no file "
            f"written: " + NOTHING_RUNNING_THERE,
            file=sys.stderr,
        )
        return EXIT_FAILED
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from deploy.recording.read import NotARecordingError, format_info, read_info

    try:
        info = read_info(args.file)
    except FileNotFoundError:
        print(f"umay info: {args.file}: no such file", file=sys.stderr)
        return EXIT_BAD_INPUT
    except NotARecordingError as exc:
        print(f"umay info: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:  # the mcap reader raises several types for a bad file
        print(f"umay info: {args.file}: not a readable MCAP file ({exc})", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(format_info(info))
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from deploy.recording.replay import REPLAYABLE, ReplayError, ReplayFailed, replay_service
    from deploy.recording.replay_check import format_report

    if args.service not in REPLAYABLE:
        choices = ", ".join(REPLAYABLE)
        print(
            f"umay replay: unknown service {args.service!r} (choose from {choices})",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    if not Path(args.file).is_file():
        print(f"umay replay: {args.file}: no such file", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.speed == "max":
        speed = None
    else:
        try:
            speed = float(args.speed)
        except ValueError:
            speed = -1.0
        if not (math.isfinite(speed) and speed > 0):
            print(f"umay replay: --speed {args.speed!r}: a positive number or max", file=sys.stderr)
            return EXIT_BAD_INPUT
    try:
        report = replay_service(
            args.file,
            args.service,
            speed,
            args.check,
            Path(args.log_dir),
            overrides=args.set,
            scenario_path=args.scenario,
            tolerance=args.tolerance,
        )
    except (ReplayError, ScenarioError) as exc:
        print(f"umay replay: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ReplayFailed as exc:
        print(f"umay replay: {exc}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    print(format_report(report))
    return 0 if report.ok else EXIT_NOT_CONVERGED


def cmd_plot(args: argparse.Namespace) -> int:
    from deploy.recording.plots import (
        FIGURE_NAMES,
        load_series,
        plot_series,
        recorded_converged_px,
    )
    from deploy.recording.read import NotARecordingError, RecordingReader

    path = Path(args.file)
    if not path.is_file():
        print(f"umay plot: {path}: no such file", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        reader = RecordingReader(path)  # a file that is not one is refused before --out is made
    except NotARecordingError as exc:
        print(f"umay plot: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    check_output_dir("--out", args.out)
    # The threshold the run converged by, as `umay run --plot` draws it, not the default.
    converged_px, notes = recorded_converged_px(reader)
    for note in notes:
        print(f"umay plot: note: {note}", file=sys.stderr)
    series = load_series(path)
    if series.runs > 1:
        print(
            f"umay plot: note: {path} holds {series.runs} runs of the sim (restarted): the last "
            "one is drawn",
            file=sys.stderr,
        )
    written = plot_series(series, Path(args.out), converged_px, source=str(path))
    for p in written:
        print(p)
    for name in sorted(set(FIGURE_NAMES) - {p.name for p in written}):
        print(f"umay plot: note: no data for {name} in {path}: left out", file=sys.stderr)
    if not written:
        print(f"umay plot: {path} holds nothing to plot", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0


def add_plot_parser(sub: argparse._SubParsersAction) -> None:
    """``umay plot``: the figures of a recording."""
    p = sub.add_parser("plot", help="figures of a recorded run (PNG)")
    p.add_argument("file", help="an MCAP recording (umay run --record / umay record)")
    p.add_argument(
        "--out",
        default="out/plots",
        help="output folder (out/plots; figures of the same name there are replaced)",
    )
    p.set_defaults(func=cmd_plot)


def add_record_parser(sub: argparse._SubParsersAction) -> None:
    """``umay record``: the running system's messages to MCAP."""
    p = sub.add_parser(
        "record",
        help="record the running system's messages to an MCAP file",
        description="Record every data message under the prefix (or --keys) to MCAP, camera "
        "frames whole, until --duration or Ctrl-C. Exit 1 when it heard nothing.",
    )
    p.add_argument("out", metavar="OUT.mcap")
    p.add_argument("--keys", default=None, help="key expression (default: <prefix>/**)")
    p.add_argument(
        "--duration", type=positive_seconds, default=None, help="seconds (default: Ctrl-C)"
    )
    p.add_argument("--prefix", type=prefix_argument, help=PREFIX_HELP)
    p.add_argument(
        "--connect",
        type=endpoints_argument,
        default=None,
        help="Zenoh endpoint(s) of the running system",
    )
    p.add_argument("--scenario", default=None, help="scenario the system runs (for a replay)")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")
    p.set_defaults(func=cmd_record)


def add_info_parser(sub: argparse._SubParsersAction) -> None:
    """``umay info``: what a recording holds."""
    p = sub.add_parser("info", help="channels, counts, rates and metadata of an MCAP recording")
    p.add_argument("file", metavar="FILE.mcap")
    p.set_defaults(func=cmd_info)


def add_replay_parser(sub: argparse._SubParsersAction) -> None:
    """``umay replay``: one service re-run on a recording."""
    p = sub.add_parser(
        "replay",
        help="re-run one service on a recording's inputs, compare",
        description="Run one service (vision, controller or actuation) as its own process on "
        "the inputs a recording holds, as fast as it answers or at --speed; --check compares "
        "what it publishes with the recorded outputs, frame by frame (exit 1 on a difference).",
    )
    p.add_argument("file", metavar="FILE.mcap")
    p.add_argument("--service", required=True, help="vision|controller|actuation")
    p.add_argument("--speed", default="max", help="playback speed factor, or max (lockstep)")
    p.add_argument("--check", action="store_true", help="compare with the recorded outputs")
    p.add_argument(
        "--tolerance",
        type=float,
        default=None,
        help="default: controller 1e-12, vision and actuation 1e-9; 0 = bit-identical",
    )
    p.add_argument("--log-dir", default="out/logs/replay", help="the service's log file")
    p.add_argument("--scenario", default=None, help="instead of the recorded scenario")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")
    p.set_defaults(func=cmd_replay)


# Command name -> what adds its parser; deploy.cli puts them in the help's order.
COMMANDS: dict[str, Callable[[argparse._SubParsersAction], None]] = {
    "plot": add_plot_parser,
    "record": add_record_parser,
    "info": add_info_parser,
    "replay": add_replay_parser,
}
