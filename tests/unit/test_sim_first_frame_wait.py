"""The sim's wait before its first lockstep frame (``SimService.wait_for_subscribers``): none
when the colour frame, the depth image and the joint state each have a subscriber, until the
last of them has one, ended by a stop, and bounded when one never comes. The sim's publishers
and node are stand-ins; ``TypedPublisher.matched`` itself is tested on real sessions
(tests/integration/test_publisher_matching.py)."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

from services.sim.node import SUBSCRIBER_WAIT_S, SimService


class Publisher:
    """Matched from its ``after``-th look on (never, for None)."""

    def __init__(self, after: int | None = 0) -> None:
        self.after = after
        self.looks = 0

    @property
    def matched(self) -> bool:
        self.looks += 1
        return self.after is not None and self.looks > self.after


def stand_in(*publishers: Publisher, stop: threading.Event | None = None) -> SimpleNamespace:
    waits: list[float] = []

    def wait_idle(seconds: float) -> None:
        waits.append(seconds)
        time.sleep(seconds)

    rgb, depth, joints = publishers
    return SimpleNamespace(
        pub_rgb=rgb,
        pub_depth=depth,
        pub_joints=joints,
        ctx=SimpleNamespace(stop=stop or threading.Event()),
        node=SimpleNamespace(wait_idle=wait_idle),
        waits=waits,
    )


def test_no_wait_when_every_first_key_has_a_subscriber() -> None:
    sim = stand_in(Publisher(), Publisher(), Publisher())
    SimService.wait_for_subscribers(sim)  # type: ignore[arg-type]
    assert sim.waits == []


def test_it_waits_until_the_last_key_has_one() -> None:
    joints = Publisher(after=3)
    sim = stand_in(Publisher(), Publisher(), joints)
    SimService.wait_for_subscribers(sim)  # type: ignore[arg-type]
    assert joints.looks == 4 and len(sim.waits) == 3


def test_it_is_bounded_when_a_key_never_gets_one() -> None:
    sim = stand_in(Publisher(), Publisher(after=None), Publisher())
    started = time.monotonic()
    SimService.wait_for_subscribers(sim)  # type: ignore[arg-type]
    waited_s = time.monotonic() - started
    assert SUBSCRIBER_WAIT_S <= waited_s < SUBSCRIBER_WAIT_S + 5.0, waited_s
    assert sim.waits  # it waited as the event loop does, not by spinning


def test_a_stop_ends_it() -> None:
    stop = threading.Event()
    stop.set()
    sim = stand_in(Publisher(None), Publisher(None), Publisher(None), stop=stop)
    SimService.wait_for_subscribers(sim)  # type: ignore[arg-type]
    assert sim.waits == []
