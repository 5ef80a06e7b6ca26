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


def _whole_number(value: str, low: int, high: int | None, says: str) -> int:
    """``value`` as an int within [low, high] (None: no upper bound), else the argparse error
    ``says``."""
    try:
        number = int(value)
    except ValueError:
        number = low - 1
    if number < low or (high is not None and number > high):
        raise argparse.ArgumentTypeError(f"{value!r}: {says}")
    return number


def tcp_port(value: str) -> int:
    """argparse type of a TCP port a user names: 0-65535 (0: any free one)."""
    return _whole_number(value, 0, 65535, "a TCP port, 0-65535 (0: any free one)")


def at_least_one(value: str) -> int:
    """argparse type of a count that must be 1 or more."""
    return _whole_number(value, 1, None, "a whole number, at least 1")


def a_seed(value: str) -> int:
    """argparse type of a random seed: a whole number, 0 or more (numpy's generators refuse
    negative ones)."""
    return _whole_number(value, 0, None, "a seed, a whole number 0 or more")


# What a tool that hears nothing says after where it looked (status, record, view).
NOTHING_RUNNING_THERE = (
    "nothing running there? (`umay up` starts the services; --prefix and --connect look elsewhere)"
)
