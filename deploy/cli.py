"""The ``umay`` command: builds the top parser from the commands each folder registers
(:mod:`deploy.launch.cli`, :mod:`deploy.recording.cli`, :mod:`deploy.foxglove.cli`,
:mod:`deploy.experiments.cli`, :mod:`deploy.bench.cli`, :mod:`deploy.docs.cli`) and dispatches,
turning the errors every command can meet into its exit code."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
from collections.abc import Callable

import zenoh

from common.node import setup_logging
from common.session import zenoh_reason
from deploy.exit_codes import EXIT_BAD_INPUT, EXIT_INTERRUPTED
from deploy.paths import OutputPathError, forget_created_folders, remove_created_folders

# `umay --help`: what the command is, where to start.
DESCRIPTION = (
    "Image-based visual servoing of the UMay arm with a depth camera, as four services over "
    "Zenoh (sim, vision, controller, actuation). Start with `umay run` (one run to "
    "convergence, then a summary), or `umay up` and `umay status` in another terminal."
)
EPILOG = "Each command's options: umay COMMAND --help. The manual: README.md and docs/."

# The order `umay --help` lists the commands in: the README's table's. A command not named
# here comes after them.
HELP_ORDER = (
    "run",
    "up",
    "service",
    "status",
    "logs",
    "record",
    "info",
    "replay",
    "plot",
    "compare",
    "campaign",
    "domains",
    "accuracy",
    "view",
    "export",
    "bench",
    "docs",
    "router",
)


def commands() -> dict[str, Callable[[argparse._SubParsersAction], None]]:
    """Every command's name -> the function adding its parser, from each folder's ``cli``."""
    from deploy.bench import cli as bench_cli
    from deploy.docs import cli as docs_cli
    from deploy.experiments import cli as experiments
    from deploy.foxglove import cli as foxglove_cli
    from deploy.launch import cli as launch
    from deploy.recording import cli as recording

    found: dict[str, Callable[[argparse._SubParsersAction], None]] = {}
    for module in (launch, recording, foxglove_cli, experiments, bench_cli, docs_cli):
        for name, add in module.COMMANDS.items():
            if name in found:  # two folders claiming one name: argparse would keep the last
                raise RuntimeError(f"umay: command {name!r} registered twice")
            found[name] = add
    return found


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="umay", description=DESCRIPTION, epilog=EPILOG)
    sub = parser.add_subparsers(dest="command", required=True)
    found = commands()
    rank = {name: i for i, name in enumerate(HELP_ORDER)}
    for name in sorted(found, key=lambda n: rank.get(n, len(rank))):
        found[name](sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    setup_logging(os.path.basename(sys.argv[0]) or "umay")
    logging.getLogger().setLevel(os.environ.get("UMAY_LOG_LEVEL", "WARNING"))
    args = build_parser().parse_args(argv)
    # SIGTERM (a CI timeout, `kill`, a container stopping) ends a command as Ctrl-C does: the
    # services it launched are stopped on the way out. Commands that run until told to stop
    # (up, router, record, compare) install their own handlers.
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    forget_created_folders()
    try:
        code = int(args.func(args))
        if code == EXIT_BAD_INPUT:  # nothing started: nor is a folder left by the checks
            remove_created_folders()
        return code
    except OutputPathError as exc:  # raised by the commands' checks, before any work starts
        print(f"umay {args.command}: {exc}", file=sys.stderr)
        remove_created_folders()
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"umay {args.command}: interrupted; what it started is stopped", file=sys.stderr)
        return EXIT_INTERRUPTED
    except zenoh.ZError as exc:  # a session that cannot open: endpoint unusable, port taken
        logging.getLogger("umay").debug("Zenoh error", exc_info=True)
        print(f"umay {args.command}: Zenoh: {zenoh_reason(exc)}", file=sys.stderr)
        return 1
