"""Who handles a node's events (common/node.py): the Zenoh thread that delivers an event, one
event at a time whichever link it came on, the idle work at its pace between them, never at the
same time; a handler's exception ends the node, raised where it spins; a latest-only input's
message that came whole, the node's own thread, which a slow handler leaves only the newest
event to. Publishers on two sessions of their own (two links) put at once, into a node on a
third."""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest
import zenoh

from common.codec import encode
from common.keys import Keys
from common.messages import Header, JointState
from common.node import Node
from common.session import free_tcp_endpoint, open_session
from tests.prefixes import unique_keys

KEYS = ("in/a", "in/b")


def state(seq: int) -> JointState:
    header = Header(seq=seq, sim_time_s=0.0, send_time_s=1.0, frame_seq=seq)
    return JointState(header=header, position_rad=[0.0] * 6, velocity_rad_s=[0.0] * 6)


@dataclass
class Handled:
    """What a handler saw: each event's key, sequence number and thread; how many handlers
    (or idle works) ran at once at most."""

    events: list[tuple[str, int, int]] = field(default_factory=list)
    inside: int = 0
    most_at_once: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)

    def enter(self) -> None:
        with self.lock:
            self.inside += 1
            self.most_at_once = max(self.most_at_once, self.inside)

    def leave(self) -> None:
        with self.lock:
            self.inside -= 1


@dataclass
class Rig:
    keys: Keys
    node: Node
    publishers: list[Any]  # one per key, each on a session of its own
    sessions: list[zenoh.Session]


@pytest.fixture()
def rig() -> Iterator[Callable[[bool], Rig]]:
    made: list[Rig] = []

    def make(latest_only: bool) -> Rig:
        endpoint = free_tcp_endpoint()
        keys = unique_keys()
        node = Node("events", keys, open_session(connect=[], listen=[endpoint]))
        for key in KEYS:
            node.subscribe(f"{keys.prefix}/{key}", JointState, latest_only=latest_only)
        sessions = [open_session(connect=[endpoint]) for _ in KEYS]
        publishers = [
            s.declare_publisher(f"{keys.prefix}/{k}") for s, k in zip(sessions, KEYS, strict=True)
        ]
        made.append(Rig(keys, node, publishers, sessions))
        return made[-1]

    yield make
    for r in made:
        for s in r.sessions:
            s.close()
        r.node.close()


def spin_in_thread(
    node: Node, on_event: Callable[[str, Any], None], timeout_s: float, on_idle=None
) -> tuple[threading.Thread, threading.Event, list[BaseException]]:
    stop, raised = threading.Event(), []

    def run() -> None:
        try:
            node.spin(stop, on_event, timeout_s=timeout_s, on_idle=on_idle)
        except BaseException as exc:  # what spin raises, for the test to see
            raised.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 10
    while node.loop_busy_s(time.monotonic()) is None:  # until it spins: events go to it now
        assert time.monotonic() < deadline and thread.is_alive(), raised
        time.sleep(0.005)
    return thread, stop, raised


def put_until(rig: Rig, done: Callable[[], bool], count: int, timeout_s: float = 20.0) -> None:
    """Each publisher puts ``count`` messages at once, from a thread of its own, again until
    ``done`` (the first ones may come before the subscriptions have reached them)."""
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, "the node did not get the messages"
        threads = [
            threading.Thread(target=lambda p=p: [p.put(encode(state(i))) for i in range(count)])
            for p in rig.publishers
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        time.sleep(0.2)


def test_events_are_handled_one_at_a_time_by_the_threads_that_deliver_them(rig) -> None:
    r = rig(False)
    seen = Handled()

    def on_event(key: str, message: JointState) -> None:
        seen.enter()
        time.sleep(0.002)  # long enough for the other link's events to come meanwhile
        seen.events.append((key, message.header.seq, threading.get_ident()))
        seen.leave()

    # The node's own thread wakes only every 30 s: every event is handled where delivered.
    thread, stop, raised = spin_in_thread(r.node, on_event, timeout_s=30.0)
    try:
        put_until(
            r, lambda: {k for k, _, _ in seen.events} == {f"{r.keys.prefix}/{k}" for k in KEYS}, 20
        )
    finally:
        stop.set()
    thread.join(40)
    assert not thread.is_alive() and not raised
    assert seen.most_at_once == 1  # never two handlers at once, though two links delivered
    assert thread.ident not in {t for _, _, t in seen.events}
    for key in KEYS:  # each link's events in the order they were put
        seqs = [s for k, s, _ in seen.events if k.endswith(key)]
        assert all(a < b or b == 0 for a, b in itertools.pairwise(seqs)), seqs


def test_the_idle_work_keeps_its_pace_under_a_stream_of_events_and_never_overlaps_one(
    rig,
) -> None:
    """Events from two links without a pause, each handled for 5 ms: the idle work (actuation's
    deadman check) still runs every ``timeout_s`` (10 ms), between events, by whichever thread
    has the turn; starved, it ran not at all for seconds while the turn went from event to
    event."""
    r = rig(False)
    seen, idle_at = Handled(), []

    def on_event(key: str, message: JointState) -> None:
        seen.enter()
        time.sleep(0.005)
        seen.events.append((key, message.header.seq, threading.get_ident()))
        seen.leave()

    def on_idle() -> None:
        seen.enter()
        idle_at.append(len(seen.events))  # how many events had been handled by then
        seen.leave()

    thread, stop, raised = spin_in_thread(r.node, on_event, timeout_s=0.01, on_idle=on_idle)
    try:
        put_until(r, lambda: len(seen.events) >= 100, 60)
    finally:
        stop.set()
    thread.join(40)
    assert not thread.is_alive() and not raised
    assert seen.most_at_once == 1
    # Each event takes 5 ms, so the idle work is due at least every third one.
    during = [n for n in idle_at if 0 < n < len(seen.events)]
    assert len(during) >= len(seen.events) // 4, (len(during), len(seen.events))


def test_a_handler_s_exception_ends_the_node_where_it_spins(rig) -> None:
    r = rig(False)

    def on_event(key: str, message: JointState) -> None:
        raise ValueError(f"bad event {message.header.seq}")

    thread, stop, raised = spin_in_thread(r.node, on_event, timeout_s=0.05)
    try:
        put_until(r, lambda: bool(raised), 1)
    finally:
        stop.set()
    thread.join(10)
    assert not thread.is_alive()
    assert isinstance(raised[0], ValueError) and "bad event" in str(raised[0])
    assert r.node.state == "stopping"  # closed on the way out


def test_a_latest_only_input_leaves_a_slow_handler_the_newest_event(rig) -> None:
    r = rig(True)
    seen = Handled()

    def on_event(key: str, message: JointState) -> None:
        seen.events.append((key, message.header.seq, threading.get_ident()))
        time.sleep(0.05)  # slower than the events come

    thread, stop, raised = spin_in_thread(r.node, on_event, timeout_s=0.05)
    try:
        put_until(r, lambda: any(s == 19 for _, s, _ in seen.events), 20)
    finally:
        stop.set()
    thread.join(10)
    assert not thread.is_alive() and not raised
    assert {t for _, _, t in seen.events} == {thread.ident}  # the node's own thread
    dropped = sum(m.dropped for m in r.node.received.values())
    assert dropped > 0 and len(seen.events) < 40  # older events replaced, not all handled
