"""The Foxglove commands of ``umay``: view (a running system, live) and export (a recording,
as a file Foxglove opens); their parsers and handlers, put together by :mod:`deploy.cli`.
The server and the converter are imported when a command runs, so ``umay --help`` stays
light."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from common.config import ScenarioError
from deploy.exit_codes import EXIT_BAD_INPUT, EXIT_NOT_CONVERGED
from deploy.paths import check_output_file


def cmd_view(args: argparse.Namespace) -> int:
    from deploy.foxglove.node import serve

    return serve(args)


def cmd_export(args: argparse.Namespace) -> int:
    from deploy.foxglove.export import export_foxglove
    from deploy.recording.read import NotARecordingError

    if not Path(args.file).is_file():
        print(f"umay export: {args.file}: no such file", file=sys.stderr)
        return EXIT_BAD_INPUT
    if not args.foxglove:
        print("umay export: say what to write: --foxglove OUT.mcap", file=sys.stderr)
        return EXIT_BAD_INPUT
    check_output_file("--foxglove", args.foxglove)
    out, recording = Path(args.foxglove), Path(args.file)
    # The same file by another name too (a hard link): opening it to write would empty it.
    if out.resolve() == recording.resolve() or (out.exists() and out.samefile(recording)):
        print("umay export: --foxglove must not overwrite the recording", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        report = export_foxglove(args.file, args.foxglove, args.jpeg_quality)
    except (NotARecordingError, ScenarioError) as exc:
        print(f"umay export: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    for topic, n in sorted(report.written.items()):
        print(f"{n:8d}  {topic}")
    print(f"{sum(report.written.values()):8d}  messages in {args.foxglove}")
    for note in report.notes:
        print(f"note: {note}", file=sys.stderr)
    if report.rejected:
        print(f"note: {report.rejected} recorded payloads did not decode", file=sys.stderr)
    return 0 if report.written else EXIT_NOT_CONVERGED


def add_view_parser(sub: argparse._SubParsersAction) -> None:
    """``umay view``: the live Foxglove view (options in :mod:`deploy.foxglove.options`)."""
    from deploy.foxglove.options import add_view_arguments

    p = sub.add_parser(
        "view",
        help="live Foxglove view of a running system (WebSocket, default ws://127.0.0.1:8765)",
    )
    add_view_arguments(p)
    p.set_defaults(func=cmd_view)


def add_export_parser(sub: argparse._SubParsersAction) -> None:
    """``umay export``: a recording as an MCAP file Foxglove shows."""
    p = sub.add_parser("export", help="a recording as an MCAP file Foxglove shows")
    p.add_argument("file", metavar="RUN.mcap")
    p.add_argument("--foxglove", default=None, metavar="OUT.mcap", help="write it here")
    p.add_argument("--jpeg-quality", type=int, default=85, help="colour images' JPEG quality")
    p.set_defaults(func=cmd_export)


# Command name -> what adds its parser; deploy.cli puts them in the help's order.
COMMANDS: dict[str, Callable[[argparse._SubParsersAction], None]] = {
    "view": add_view_parser,
    "export": add_export_parser,
}
