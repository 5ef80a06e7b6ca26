"""Options of ``umay view`` (kept apart from the server so ``umay --help`` stays light)."""

from __future__ import annotations

import argparse

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765


def view_arguments(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="umay view", description="live Foxglove view of a run")
    add_view_arguments(p)
    return p.parse_args(argv)


def add_view_arguments(p: argparse.ArgumentParser) -> None:
    """Every option of ``umay view`` (also the ``view`` subcommand of ``umay``)."""
    from common.keys import PREFIX_HELP
    from common.runtime import endpoints_argument, prefix_argument

    add_view_options(p)
    p.add_argument("--prefix", type=prefix_argument, help=PREFIX_HELP)
    p.add_argument(
        "--connect", type=endpoints_argument, default=None, help="Zenoh endpoint(s) of the system"
    )
    p.add_argument("--scenario", default=None, help="scenario the system runs (default.toml)")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")


def add_view_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", default=DEFAULT_HOST, help="WebSocket address (default 127.0.0.1)")
    p.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help="WebSocket port (default 8765; 0: any)"
    )
    p.add_argument(
        "--rate-hz", type=float, default=15.0, help="messages per key and s at most (15)"
    )
    p.add_argument("--image-hz", type=float, default=10.0, help="colour images per s at most")
    p.add_argument("--depth-hz", type=float, default=2.0, help="depth images per s at most")
    p.add_argument("--jpeg-quality", type=int, default=80, help="1-100")


def check_view_options(args: argparse.Namespace) -> str | None:
    """What is wrong with the options (None: nothing)."""
    if not 0 <= args.port <= 65535:
        return f"--port {args.port}: 0-65535"
    if not (args.rate_hz > 0 and args.image_hz > 0 and args.depth_hz > 0):
        return "--rate-hz, --image-hz and --depth-hz: above 0"
    if not 1 <= args.jpeg_quality <= 100:
        return f"--jpeg-quality {args.jpeg_quality}: 1-100"
    return None
