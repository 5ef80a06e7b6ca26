"""Every Zenoh key expression of the system, in one place, under one configurable prefix.

Default prefix: ``umay/<robot_id>`` with ``robot_id`` from ``UMAY_ROBOT_ID`` (default
``umay1``); ``UMAY_PREFIX`` or ``--prefix`` replaces the whole prefix (tests use a unique one
per test so parallel runs never cross).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import zenoh

SERVICES: tuple[str, ...] = ("sim", "vision", "controller", "actuation")

# Data keys, relative to the prefix.
RGB = "sim/rgb"
DEPTH = "sim/depth"
JOINT_STATE = "sim/joint_state"
TRUTH = "sim/truth"
TIMING = "sim/timing"
FEATURES = "vision/features"
TWIST = "controller/twist"
JOINT_COMMAND = "actuation/joint_command"


WHOLE_FRAME = "whole"  # queryable under a camera stream's key: its whole frames


def whole_frame_key(key: str) -> str:
    """The queryable of a camera stream on ``key`` that answers with the whole frame of a
    reference (``?segment=S;seq=N``), for subscribers that cannot map the publisher's
    shared-memory ring (see :mod:`common.publishers`)."""
    return f"{key}/{WHOLE_FRAME}"


ENV_PREFIX = "UMAY_PREFIX"  # the key prefix of every command without --prefix
ENV_ROBOT_ID = "UMAY_ROBOT_ID"  # else umay/<robot id>
PREFIX_HELP = "Zenoh key prefix (default: $UMAY_PREFIX, else umay/$UMAY_ROBOT_ID, else umay/umay1)"


def default_prefix() -> str:
    explicit = os.environ.get(ENV_PREFIX)
    if explicit:
        return explicit
    return f"umay/{os.environ.get(ENV_ROBOT_ID, 'umay1')}"


def check_prefix(prefix: str) -> str:
    """``prefix`` if it can prefix every key: a Zenoh key expression (no empty chunk, no
    leading or trailing slash) without wildcards; else ValueError saying why."""
    if any(c in prefix for c in "*$?#"):
        raise ValueError(f"invalid key prefix {prefix!r}: no wildcards (* $ ? #)")
    try:
        zenoh.KeyExpr(prefix)
    except zenoh.ZError:
        raise ValueError(
            f"invalid key prefix {prefix!r}: empty, or with an empty chunk or a leading or "
            "trailing slash"
        ) from None
    return prefix


@dataclass(frozen=True)
class Keys:
    prefix: str

    def __post_init__(self) -> None:
        check_prefix(self.prefix)

    # sim
    @property
    def rgb(self) -> str:
        return f"{self.prefix}/{RGB}"

    @property
    def depth(self) -> str:
        return f"{self.prefix}/{DEPTH}"

    @property
    def joint_state(self) -> str:
        return f"{self.prefix}/{JOINT_STATE}"

    @property
    def truth(self) -> str:
        """Ground truth for evaluation only (supervisor, tests); never for perception/control."""
        return f"{self.prefix}/{TRUTH}"

    @property
    def timing(self) -> str:
        """The sim's per-frame timing (render, publication, commands applied): benchmarks."""
        return f"{self.prefix}/{TIMING}"

    # vision → controller → actuation → sim
    @property
    def features(self) -> str:
        return f"{self.prefix}/{FEATURES}"

    @property
    def twist(self) -> str:
        return f"{self.prefix}/{TWIST}"

    @property
    def joint_command(self) -> str:
        return f"{self.prefix}/{JOINT_COMMAND}"

    def status(self, service: str) -> str:
        return f"{self.prefix}/{service}/status"

    def stamps(self, service: str) -> str:
        """Queryable: the header stamps of what ``service`` published last (``umay bench``)."""
        return f"{self.prefix}/{service}/stamps"

    def relative(self, key: str) -> str:
        """``key`` without the prefix (``vision/features``)."""
        return key.removeprefix(f"{self.prefix}/")

    def alive(self, service: str, pid: int) -> str:
        """The liveliness token of one process of ``service``: one key per process, since
        Zenoh reports a key alive once, however many tokens hold it, so a restarted service's
        token on the same key as the one it replaced could go unnoticed."""
        return f"{self.prefix}/alive/{service}/{pid}"

    @property
    def all_status(self) -> str:
        return f"{self.prefix}/*/status"

    @property
    def all_alive(self) -> str:
        return f"{self.prefix}/alive/*/*"

    @staticmethod
    def alive_service(key: str) -> str:
        """The service whose token ``key`` is (:meth:`alive`)."""
        return key.split("/")[-2]
