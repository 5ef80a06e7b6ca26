"""``umay docs`` on the command line: its parser and handler, apart from the blocks (which load
the comparison's modules) so that building the ``umay`` parser stays light."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from deploy.exit_codes import EXIT_BAD_INPUT


def cmd_docs(args: argparse.Namespace) -> int:
    from deploy.docs.documents import update
    from deploy.docs.figures import redraw
    from deploy.docs.sources import REPO_ROOT, DocsError, load_inputs

    root = Path(args.root) if args.root else REPO_ROOT
    try:
        inputs = load_inputs(root)  # once, for the tables and the figures
        outdated = update(root, check=args.check, inputs=inputs)
        figures = [] if args.check else redraw(root, inputs)
    except DocsError as exc:
        print(f"umay docs: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    for o in outdated:
        print(o if args.check else f"rewrote {o.document}: {o.block}", file=sys.stderr)
    for f in figures:
        print(f"redrew {f}", file=sys.stderr)
    return 1 if args.check and outdated else 0


def add_docs_parser(sub: argparse._SubParsersAction) -> None:
    """``umay docs``: the docs' generated tables."""
    p = sub.add_parser(
        "docs", help="rewrite the docs' tables (and redraw their figures) from their JSON"
    )
    p.add_argument("--check", action="store_true", help="change nothing; exit 1 if out of date")
    p.add_argument("--root", default=None, help="the repository (default: this one)")
    p.set_defaults(func=cmd_docs)


# Command name -> what adds its parser; deploy.cli puts them in the help's order.
COMMANDS: dict[str, Callable[[argparse._SubParsersAction], None]] = {
    "docs": add_docs_parser,
}
