"""A small node base for the services: typed publishers and subscribers, one event inbox,
status, liveliness and published stamps.

A node declares typed publishers and subscribers; subscriber callbacks (run on the Zenoh thread
that receives the sample) decode and validate, then put the message in the node's inbox. Its
events are handled one at a time, so service state is touched by one thread at a time (as in
dora-rs nodes):

- under :meth:`Node.spin`, by the thread that delivers the event, at once when no other is
  handling one (else the event waits in the inbox for that one), the idle work done by
  whichever thread has the turn when it is due, or by the node's own thread when none has. No
  thread is woken to hand an event over: on a host whose idle CPUs sleep, that wake-up is a
  good part of a hop (docs/performance.md). Only a latest-only input's message that came whole
  goes to the node's own thread, so that a slow consumer finds only the newest one waiting:
  the next one may come on the very thread that would be busy with it (a frame sent by
  reference is the consumer's to skip when it is superseded: vision does);
- under a loop of the service's own around :meth:`Node.next_event` (the sim's clock), by the
  node's own thread, which each event wakes.

A payload that fails validation is counted, its reason kept and logged at a limited rate; it
never reaches the service and never kills it.

Frames by reference: :mod:`common.publishers`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

import zenoh
from pydantic import BaseModel

from common.codec import DEFAULT_MAX_BYTES, encode, image_field
from common.frame_ring import RingReader
from common.keys import Keys
from common.messages import Header, PublishedStamps, ServiceStatus, StatusFields
from common.metrics import DurationMeter, TopicMeter
from common.publishers import TypedPublisher, decode_or_fetch, typed_publisher

M = TypeVar("M", bound=BaseModel)
log = logging.getLogger("umay")

# How often a waiting spin() looks at its stop event, which cannot wake it.
STOP_POLL_S = 0.1

# The longest reason a status carries: a rejection's reason quotes what the sender chose (a
# field name, say), and a status too large to decode would have the service taken for hung.
MAX_REASON_CHARS = 500


def clipped(text: str, limit: int = MAX_REASON_CHARS) -> str:
    """``text``, cut to ``limit`` characters with an ellipsis when longer."""
    return text if len(text) <= limit else text[: limit - 1] + "…"


class Node:
    """One service: a Zenoh session, typed pub/sub, a status queryable, a liveliness token.

    ``status_fields`` returns the service-specific part of the status answer, the service's
    own :class:`StatusFields` (none: no fields).
    """

    def __init__(
        self,
        service: str,
        keys: Keys,
        session: zenoh.Session,
        status_fields: Callable[[], StatusFields] = StatusFields,
        degraded_reason: Callable[[], str] = str,
    ) -> None:
        self.service = service
        self.keys = keys
        self.session = session
        self.state = "starting"
        self._status_fields = status_fields
        self._degraded_reason = degraded_reason
        self.processing = DurationMeter()
        self._started = time.monotonic()
        self._seq = 0
        self._lock = threading.RLock()  # the inbox, the counters, whose turn it is
        self._cond = threading.Condition(self._lock)  # an event for the node's own thread
        # Held while the status answer is built (on a Zenoh thread) and by every put of the
        # node's publishers, so that one answer never shows half of a put (a camera frame
        # counted by its publisher but not yet by its ring, say).
        self.counting = threading.Lock()
        # (key, message, wall-clock receive time): the time goes into the headers of what
        # handling the message publishes (Header.recv_time_s), for per-hop latency.
        self._inbox: deque[tuple[str, BaseModel, float]] = deque()
        self.event_recv_time_s = 0.0  # receive time of the event next_event returned last
        self._handling_recv_time_s = 0.0  # ... while spin() handles it, else 0
        self._publishers: dict[str, TypedPublisher[Any]] = {}
        self._subscribers: list[Any] = []
        self.received: dict[str, TopicMeter] = {}
        self.rejected = 0
        self.last_rejection = ""
        self._last_reject_log = 0.0
        self._closed = False
        # spin()'s handler when events are handled by the thread that delivers them, whether
        # a thread is handling events (or the idle work) now, and what a handler raised on a
        # Zenoh thread, for spin() to raise in the node's own.
        self._handler: Callable[[str, Any], None] | None = None
        self._on_idle: Callable[[], None] | None = None  # spin()'s, due every _idle_every_s
        self._idle_every_s = 0.1
        self._last_idle_s = 0.0
        self._turn_taken = False
        self._turn_free = threading.Condition(self._lock)
        self._failure: BaseException | None = None
        self._fields_broken = False  # its status fields failed once (logged then)
        # When the event loop last left next_event (None: it has not called it yet) and
        # whether it is inside it now: the status's loop_busy_s, read by the supervisor.
        self._loop_left_s: float | None = None
        self._loop_waiting = False
        self._queryable = session.declare_queryable(keys.status(service), self._answer_status)
        self._stamps_queryable = session.declare_queryable(
            keys.stamps(service), self._answer_stamps
        )
        self._token: Any = None

    def ready(self) -> None:
        """Subscriptions are in place: announce liveliness and report ``running``."""
        self.state = "running"
        token_key = self.keys.alive(self.service, os.getpid())
        self._token = self.session.liveliness().declare_token(token_key)
        log.info(
            "%s running under %s; in: %s; out: %s",
            self.service,
            self.keys.prefix,
            ", ".join(self.keys.relative(k) for k in self.received) or "-",
            ", ".join(self.keys.relative(k) for k in self._publishers) or "-",
        )

    # --- publishing -------------------------------------------------------------------
    def publisher(self, key: str, block: bool = True, frames: bool = False) -> TypedPublisher[Any]:
        """``block``: back-pressure instead of dropping when the network is congested.
        ``frames``: camera frames, sent by reference through a shared-memory ring
        (:class:`RingPublisher`) unless shared memory is off."""
        pub = typed_publisher(self.session, key, block, frames, self.counting)
        self._publishers[key] = pub
        return pub

    def header(
        self, sim_time_s: float, frame_seq: int, recv_time_s: float | None = None, run: int = 0
    ) -> Header:
        """A fresh header: per-node sequence number, wall-clock send time, and the receive time
        of the event being handled by :meth:`spin` (0 outside one) unless ``recv_time_s``;
        ``run``: the sim's run the message derives from (:mod:`common.runs`)."""
        recv = self._handling_recv_time_s if recv_time_s is None else recv_time_s
        h = Header(
            seq=self._seq,
            sim_time_s=sim_time_s,
            send_time_s=time.time(),
            frame_seq=frame_seq,
            recv_time_s=recv,
            run=run,
        )
        self._seq += 1
        return h

    # --- subscribing ------------------------------------------------------------------
    def count_dropped(self, key: str, n: int = 1) -> None:
        """``n`` messages on ``key`` dropped by the service itself (stale, superseded); under
        the lock the subscriber callbacks count theirs with, so no count is lost."""
        with self._cond:
            self.received[key].dropped += n

    def subscribe(
        self,
        key: str,
        model: type[M],
        max_bytes: int = DEFAULT_MAX_BYTES,
        latest_only: bool = False,
        rings: RingReader | None = None,
    ) -> None:
        """Deliver validated ``model`` messages on ``key`` as the node's events (to
        :meth:`spin`'s handler, or :meth:`next_event`: the module's docstring says by which
        thread).

        ``latest_only``: an undelivered older message on the same key is replaced (and counted
        as dropped), so a slow consumer always works on the newest data; under :meth:`spin`,
        such a message that came whole is handled by the node's own thread for that reason.
        ``rings``: what maps the publisher's ring for camera frames sent by reference
        (default: the process's :func:`~common.frame_ring.shared_reader`); a frame it cannot
        map is asked whole from the publisher (:func:`~common.publishers.decode_or_fetch`).
        """
        meter = self.received[key] = TopicMeter()
        field = image_field(model)
        newest = (0, -1)  # header.run and .seq of the newest message delivered on this key

        def deliver(message: BaseModel, received: float, by_ref: bool, fetched: bool) -> None:
            nonlocal newest
            header = getattr(message, "header", None)
            run, seq = (header.run, header.seq) if isinstance(header, Header) else (0, -1)
            with self._cond:
                # A frame asked for whole after a newer one came: late. Only within one run of
                # its publisher, whose sequence numbers begin again when it restarts.
                if fetched and run == newest[0] and seq < newest[1]:
                    meter.dropped += 1
                    return
                if run != newest[0] or seq > newest[1]:
                    newest = (run, seq)
                meter.tick()
                if field is not None:
                    meter.by_ref += by_ref
                    meter.by_copy += not by_ref
                    meter.fetched += fetched
                if latest_only:
                    for i, (k, _, _) in enumerate(self._inbox):
                        if k == key:
                            del self._inbox[i]
                            meter.dropped += 1
                            break
                self._inbox.append((key, message, received))
                # The node's own thread takes it: outside spin(), and a latest-only input's
                # message that came whole, whose thread may be the one the next would come on.
                if self._handler is None or (latest_only and not by_ref):
                    self._cond.notify()
                    return
                if self._turn_taken or self._failure is not None:
                    return  # the thread handling events now takes this one after its own
                self._take_turn()
            self._handle_inbox()

        def on_sample(sample: zenoh.Sample) -> None:
            received = time.time()  # before the copy and decode: those count as processing

            def on_message(message: BaseModel, fetched_s: float | None) -> None:
                if fetched_s is not None:  # asked whole from its publisher: received as it came
                    deliver(message, fetched_s, by_ref=False, fetched=True)
                    return
                by_ref = field is not None and getattr(message, field).ring_ref is not None
                deliver(message, received, by_ref, fetched=False)

            decode_or_fetch(
                self.session,
                key,
                sample.payload.to_bytes(),
                model,
                max_bytes,
                on_message,
                lambda reason: self._reject(key, reason),
                rings,
            )

        self._subscribers.append(self.session.declare_subscriber(key, direct(on_sample)))

    def next_event(self, timeout_s: float | None) -> tuple[str, Any] | None:
        """The next ``(key, message)``, or None after ``timeout_s`` or when closed."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._cond, self._loop_waits():
            while not self._inbox and not self._closed:
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._cond.wait(remaining)
            if not self._inbox:
                return None
            key, message, self.event_recv_time_s = self._inbox.popleft()
            return key, message

    def wait_idle(self, seconds: float) -> None:
        """Wait ``seconds`` (less once closed) as the event loop waits for input, taking no
        event: a wait before the loop's first event (the sim's for its peers) is then not
        taken for a start that hangs (the status's ``loop_busy_s`` is 0, not None)."""
        with self._cond, self._loop_waits():
            self._cond.wait_for(lambda: self._closed, seconds)

    @contextlib.contextmanager
    def _loop_waits(self) -> Iterator[None]:
        """The event loop waiting for input (with the lock held): ``loop_busy_s`` is 0 inside,
        and counts from when it leaves."""
        self._loop_waiting = True
        try:
            yield
        finally:
            self._loop_waiting = False
            self._loop_left_s = time.monotonic()

    def reject(self, key: str, reason: str) -> None:
        """Count a message on ``key`` the service could not use (a frame whose ring slot was
        overwritten while it was in use): as a payload that failed validation."""
        self._reject(key, reason)

    def _reject(self, key: str, reason: str) -> None:
        with self._cond:
            self.rejected += 1
            self.last_rejection = clipped(f"{key}: {reason}")
        now = time.monotonic()
        if now - self._last_reject_log > 1.0:  # rate-limited: a flood must not flood the log
            self._last_reject_log = now
            log.warning(
                "%s rejected a message (%d so far): %s", self.service, self.rejected, reason
            )

    # --- status -----------------------------------------------------------------------
    def status(self) -> ServiceStatus:
        with self.counting:
            return self._status()

    def _status(self) -> ServiceStatus:
        now = time.monotonic()
        fields, broken = self._fields()
        reason = self._degraded_reason() if self.state == "running" else ""
        reason = "; ".join(r for r in (reason, broken) if r)
        p50, p99 = self.processing.percentiles()
        return ServiceStatus(
            service=self.service,
            pid=os.getpid(),
            host=socket.gethostname(),
            uptime_s=now - self._started,
            state="degraded" if reason else self.state,  # type: ignore[arg-type]
            degraded_reason=clipped(reason),
            # Copies (list() holds the GIL throughout): the main thread may add a key meanwhile.
            received={k: m.stats(now) for k, m in list(self.received.items())},
            published={k: p.meter.stats(now) for k, p in list(self._publishers.items())},
            rejected=self.rejected,
            last_rejection=self.last_rejection,
            processing_ms_p50=p50,
            processing_ms_p99=p99,
            loop_busy_s=self.loop_busy_s(now),
            fields=fields,
        )

    def _fields(self) -> tuple[dict[str, Any], str]:
        """The service's own fields, and "" (or why there are none: a field its model refuses).
        The answer goes out without them rather than not at all, which the supervisor would
        take for a hung service and kill. None while it starts: the status is answered from
        the node's construction on, before the service object around it is built."""
        if self.state == "starting":
            return {}, ""
        try:
            return self._status_fields().model_dump(), ""
        except Exception as exc:
            if not self._fields_broken:  # once: status is asked every second
                log.exception("%s: its status fields failed", self.service)
            self._fields_broken = True
            return {}, f"status fields: {type(exc).__name__}: {str(exc).splitlines()[0]}"

    def loop_busy_s(self, now_s: float) -> float | None:
        """Seconds since the event loop left :meth:`next_event` (0 while it is inside)."""
        if self._loop_waiting:  # its first wait included: a loop waiting for input has started
            return 0.0
        left = self._loop_left_s
        return None if left is None else max(0.0, now_s - left)

    def _answer_status(self, query: zenoh.Query) -> None:
        try:
            query.reply(self.keys.status(self.service), encode(self.status()))
        except Exception:  # a status reply must never take the service down
            log.exception("%s: status reply failed", self.service)

    def published_stamps(self) -> PublishedStamps:
        return PublishedStamps(
            service=self.service,
            stamps={self.keys.relative(k): list(p.stamps) for k, p in self._publishers.items()},
        )

    def _answer_stamps(self, query: zenoh.Query) -> None:
        try:
            query.reply(self.keys.stamps(self.service), encode(self.published_stamps()))
        except Exception:  # as for status: a diagnostic must never take the service down
            log.exception("%s: stamps reply failed", self.service)

    def spin(
        self,
        stop: threading.Event,
        on_event: Callable[[str, Any], None],
        timeout_s: float = 0.1,
        on_idle: Callable[[], None] | None = None,
    ) -> None:
        """The node's events handled until ``stop``, then the node closed (the module's
        docstring says by which threads); ``on_idle`` run at least every ``timeout_s``, by
        the thread handling events then or by this one. An exception from either ends the
        node, raised here."""
        self.ready()
        try:
            self._spin(stop, on_event, timeout_s, on_idle)
        finally:
            self.close()

    def _spin(
        self,
        stop: threading.Event,
        on_event: Callable[[str, Any], None],
        timeout_s: float,
        on_idle: Callable[[], None] | None,
    ) -> None:
        with self._cond:
            self._handler, self._on_idle, self._idle_every_s = on_event, on_idle, timeout_s
            self._last_idle_s = time.monotonic()
            self._loop_waiting = True  # started: loop_busy_s counts a turn from here on
        try:
            while not stop.is_set():
                with self._cond:
                    # Until the idle work is due, an event is left to this thread, or stop.
                    due = time.monotonic() + timeout_s
                    while not self._inbox and not stop.is_set() and time.monotonic() < due:
                        self._cond.wait(min(due - time.monotonic(), STOP_POLL_S))
                    while self._turn_taken and self._failure is None and not stop.is_set():
                        self._turn_free.wait(STOP_POLL_S)  # stop noticed, a hung handler or not
                    if self._failure is not None or stop.is_set():
                        break
                    if not self._inbox and not (self._on_idle is not None and self._idle_due()):
                        continue  # nothing to do: no empty turn (another thread did the idle)
                    self._take_turn()
                self._handle_inbox()
        finally:
            with self._cond:  # none handled from now on; the one being handled may finish
                self._handler = self._on_idle = None
                self._turn_free.wait_for(lambda: not self._turn_taken, timeout=timeout_s)
                failure = self._failure
        if failure is not None:
            raise failure

    def _take_turn(self) -> None:
        """This thread handles the node's events now (the lock held)."""
        self._turn_taken = True
        self._loop_waiting = False
        self._loop_left_s = time.monotonic()

    def _give_turn_back(self) -> None:
        """No thread handles events now (the lock held)."""
        self._turn_taken = False
        self._loop_waiting = True
        self._turn_free.notify_all()

    def _handle_inbox(self) -> None:
        """The inbox's events handled in this thread, which has the turn, until none is left
        (also those that came meanwhile), the idle work done whenever it is due; then the turn
        given back. What they raise is kept for :meth:`spin` to raise: this may be a Zenoh
        thread, which would only log it."""
        try:
            while True:
                on_idle = self._on_idle  # once: spin() may be ending and clear it meanwhile
                if on_idle is not None and self._idle_due():
                    self._last_idle_s = time.monotonic()
                    on_idle()
                with self._cond:
                    handler = self._handler
                    if not self._inbox or handler is None or self._failure is not None:
                        self._give_turn_back()
                        return
                    key, message, received = self._inbox.popleft()
                    self._loop_left_s = time.monotonic()
                self._handle(handler, key, message, received)
        except BaseException as exc:
            with self._cond:
                self._failure = exc
                self._give_turn_back()

    def _idle_due(self) -> bool:
        return time.monotonic() - self._last_idle_s >= self._idle_every_s

    def _handle(
        self, on_event: Callable[[str, Any], None], key: str, message: Any, received_s: float
    ) -> None:
        """One event, timed; what it publishes carries ``received_s``, when it was received."""
        started = time.perf_counter()
        self._handling_recv_time_s = received_s
        try:
            on_event(key, message)
        finally:
            self._handling_recv_time_s = 0.0
        self.processing.add(1000.0 * (time.perf_counter() - started))

    def close(self) -> None:
        """Undeclare everything and close the session; once (a second call does nothing)."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        self.state = "stopping"
        try:
            for s in self._subscribers:
                s.undeclare()
            for p in self._publishers.values():
                if p.frames is not None:
                    p.frames.close()  # the ring's segment is unlinked
            self._queryable.undeclare()
            self._stamps_queryable.undeclare()
            if self._token is not None:
                self._token.undeclare()
        finally:  # whatever failed above, the session's threads must not outlive the node
            self.session.close()


def direct(callback: Callable[[zenoh.Sample], None]) -> Any:
    """``callback`` run on the Zenoh thread that receives the sample rather than on a thread of
    its own that Zenoh hands it to: one thread wake-up less per message (docs/performance.md).
    As given where this Zenoh lacks that option (``indirect``, marked unstable)."""
    try:
        return zenoh.handlers.Callback(callback, indirect=False)
    except (AttributeError, TypeError):
        return callback


def setup_logging(service: str) -> None:
    logging.basicConfig(
        level=os.environ.get("UMAY_LOG_LEVEL", "INFO"),
        format=f"%(asctime)s {service} %(levelname)s %(message)s",
    )
