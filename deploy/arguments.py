"""What commands of more than one folder share: argparse types (``umay status`` and ``umay
record`` both take a duration) and what a tool says when it hears nothing."""

from __future__ import annotations

import argparse
import math


def positive_seconds(value: str) -> float:
    """argparse type of a duration: a finite number of seconds above 0."""
    try:
        seconds = float(value)
    except ValueError:
        seconds = math.nan
    if not (math.isfinite(seconds) and seconds > 0):
        raise argparse.ArgumentTypeError(f"{value!r}: seconds, a finite number above 0")
    return seconds


def tcp_port(value: str) -> int:
    """argparse type of a TCP port a user names: 0-65535 (0: any free one)."""
    try:
        port = int(value)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{value!r}: a TCP port, 0-65535 (0: any free one)")
    return port


def at_least_one(value: str) -> int:
    """argparse type of a count that must be 1 or more."""
    try:
        count = int(value)
    except ValueError:
        count = 0
    if count < 1:
        raise argparse.ArgumentTypeError(f"{value!r}: a whole number, at least 1")
    return count


# What a tool that hears nothing says after where it looked (status, record, view).
NOTHING_RUNNING_THERE = (
    "nothing running there? (`umay up` starts the services; --prefix and --connect look elsewhere)"
)
