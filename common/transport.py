"""Zenoh helpers: session configuration and a small node base with one event inbox.

A node declares typed publishers and subscribers; subscriber callbacks (Zenoh threads) only
decode and validate, then hand the message to the node's single event loop through
:meth:`Node.next_event`, so service state is touched by one thread only (as in dora-rs nodes).
A payload that fails validation is counted, its reason kept and logged at a limited rate; it
never reaches the service and never kills it.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import zenoh
from pydantic import BaseModel

from common.codec import (
    DEFAULT_MAX_BYTES,
    MessageError,
    decode,
    encode,
    frame_parts,
    image_field,
)
from common.keys import Keys
from common.messages import Header, PublishedStamps, ServiceStatus, Stamp
from common.metrics import DurationMeter, TopicMeter

M = TypeVar("M", bound=BaseModel)

ENV_CONFIG = "UMAY_ZENOH_CONFIG"  # path of a Zenoh JSON5 config file: used as is
ENV_CONNECT = "UMAY_ZENOH_CONNECT"  # comma-separated endpoints to connect to
# "0": no shared memory, so payloads take the network path even between processes on one host
# (what a peer on another host gets); benchmarks compare both. Applies to config files too.
ENV_SHM = "UMAY_ZENOH_SHM"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"  # where `umay up` listens and tools connect

log = logging.getLogger("umay")


class ZenohConfigError(ValueError):
    """A Zenoh config file that cannot be read; the message names the file and the reason."""


def zenoh_config(
    config_path: str | None = None,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
) -> zenoh.Config:
    """Peer mode, loopback only, multicast scouting off, unless a config file says otherwise.

    Precedence: ``config_path`` argument, then ``$UMAY_ZENOH_CONFIG``, then the defaults with
    ``connect`` (argument, else ``$UMAY_ZENOH_CONNECT``, else :data:`DEFAULT_ENDPOINT`).
    Peers find each other through gossip over the first connection. With a config file, an
    explicit ``connect`` (argument or environment) replaces the file's endpoints, so one file
    (say a client's credentials) serves wherever the router happens to be.

    Zenoh's shared memory is on by default: between processes on one host, payloads above
    3 KB (camera frames) go through a shared pool instead of the socket, and a peer that
    cannot map it (another host) gets them over the network. ``$UMAY_ZENOH_SHM=0`` turns it
    off.
    """
    cfg = _base_config(config_path, connect, listen)
    if not shm_enabled():
        cfg.insert_json5("transport/shared_memory/enabled", "false")
    return cfg


def _base_config(
    config_path: str | None, connect: list[str] | None, listen: list[str] | None
) -> zenoh.Config:
    if connect is None:
        env = os.environ.get(ENV_CONNECT, "")
        connect = [e for e in env.split(",") if e] or None
    path = config_path or os.environ.get(ENV_CONFIG)
    if path:
        try:
            cfg = zenoh.Config.from_file(path)
            if connect:
                cfg.insert_json5("connect/endpoints", json.dumps(connect))
        except zenoh.ZError as exc:
            raise ZenohConfigError(f"{path}: not a usable Zenoh config: {exc}") from exc
        return cfg
    connect = connect if connect is not None else [DEFAULT_ENDPOINT]
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("listen/endpoints", json.dumps(listen or ["tcp/127.0.0.1:0"]))
    cfg.insert_json5("connect/endpoints", json.dumps(connect))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return cfg


def check_endpoints(value: str) -> list[str]:
    """The comma-separated Zenoh endpoints in ``value`` (``tcp/127.0.0.1:7447,...``), each
    checked by Zenoh's own parser; ValueError naming the first bad one and why."""
    endpoints = [e.strip() for e in value.split(",")]
    for endpoint in endpoints:
        try:
            zenoh.Config().insert_json5("connect/endpoints", json.dumps([endpoint]))
        except zenoh.ZError:
            raise ValueError(
                f"invalid endpoint {endpoint!r}: expected <protocol>/<address>[?<metadata>], "
                f"e.g. {DEFAULT_ENDPOINT}"
            ) from None
    return endpoints


def open_session(
    config_path: str | None = None,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
) -> zenoh.Session:
    """A session on :func:`zenoh_config` (opened by :func:`open_zenoh`). Raises
    :class:`ZenohConfigError` for a bad config file, ``zenoh.ZError`` if it cannot open."""
    return open_zenoh(zenoh_config(config_path, connect, listen))


def open_zenoh(config: zenoh.Config) -> zenoh.Session:
    """``zenoh.open(config)``; where the host cannot give Zenoh shared memory (no writable
    ``/dev/shm``, as in some containers, where Zenoh fails to open at all) it opens without
    it, with a warning: large payloads then go over the network."""
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        # Only for shared memory's errors ("Unable to create POSIX shm segment"): a retry
        # after any other (a router that does not answer) would double the wait for nothing.
        if "shm" not in str(exc).lower():
            raise
        config.insert_json5("transport/shared_memory/enabled", "false")
        try:
            session = zenoh.open(config)
        except zenoh.ZError:
            raise exc from None  # the first error is the one to report
        log.warning("Zenoh session opened without shared memory (%s)", zenoh_reason(exc))
        return session


def zenoh_reason(exc: zenoh.ZError) -> str:
    """A Zenoh error's message without the Rust source location that ends it."""
    return str(exc).split(" at /", 1)[0]


def free_tcp_endpoint() -> str:
    """A loopback endpoint on a port that is free right now (for tests and the supervisor)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


class ShmFrameWriter:
    """Writes camera frames straight into a Zenoh shared-memory pool of this publisher's own.

    Handing Zenoh ``bytes`` costs two fresh buffers of the frame's size per put (the encoded
    payload, then Zenoh's own copy, before its shared-memory copy): at 640×480, 0.66 ms per
    image against 0.07 ms here, where the frame is assembled in a buffer kept from frame to
    frame and copied once into a pool chunk. Zenoh sends the chunk by reference to peers on
    this host that map the pool, and its bytes over the network to the others (another host,
    shared memory disabled); when the pool is full (subscribers still hold old frames) the
    frame goes as an ordinary put. The pool holds :data:`POOL_FRAMES` frames of the first
    frame's size (4 to 64 MiB). Where the host cannot give one (a small or read-only
    ``/dev/shm``, as in many containers) every frame goes as an ordinary put, and
    :attr:`unavailable` says why."""

    POOL_FRAMES = 8

    def __init__(self) -> None:
        self._provider: Any = None
        self._scratch = bytearray()
        self.fallbacks = 0  # frames put without the pool (none, exhausted, or too small)
        self.unavailable = ""  # why there is no pool ("": there is one, or not yet)

    def payload(self, parts: tuple[bytes, memoryview]) -> Any:
        """The frame as a pool chunk to put (or as a bytearray when the pool cannot take it)."""
        import zenoh.shm as zshm

        size = sum(len(p) for p in parts)
        if len(self._scratch) != size:  # reallocated only when the frame size changes
            self._scratch = bytearray(size)
        view, offset = memoryview(self._scratch), 0
        for part in parts:
            view[offset : offset + len(part)] = part
            offset += len(part)
        if self._provider is None and not self.unavailable:
            self._provider = self._open_pool(size)
        if self._provider is None:
            self.fallbacks += 1
            return self._scratch
        try:
            chunk = self._provider.alloc(size, policy=zshm.GarbageCollect())  # never blocks
        except zenoh.ZError:
            self.fallbacks += 1
            return self._scratch
        chunk[:] = self._scratch  # this wheel's chunks take only bytes/bytearray
        return chunk

    def _open_pool(self, frame_bytes: int) -> Any:
        """A pool for :data:`POOL_FRAMES` frames, or None (the reason kept and logged once)."""
        import zenoh.shm as zshm

        pool_bytes = min(max(self.POOL_FRAMES * frame_bytes, 4 << 20), 64 << 20)
        try:
            return zshm.ShmProvider.default_backend(pool_bytes)
        except zenoh.ZError as exc:
            reason = zenoh_reason(exc)
            self.unavailable = f"no shared-memory pool of {pool_bytes / 2**20:.1f} MiB ({reason})"
            log.warning("%s: camera frames go over the network", self.unavailable)
            return None


def shm_enabled() -> bool:
    """False when ``$UMAY_ZENOH_SHM=0`` turns Zenoh's shared memory off."""
    return os.environ.get(ENV_SHM, "").strip() != "0"


STAMPS_KEPT = 4096  # per key: about 2 min of a 30 Hz stream
STAMPS_MAX_BYTES = 1 << 20  # a stamps reply: the sim has 5 keys × 4096 stamps × ≤ 24 bytes


@dataclass
class TypedPublisher(Generic[M]):
    key: str
    publisher: Any
    meter: TopicMeter = field(default_factory=TopicMeter)
    frames: ShmFrameWriter | None = None  # camera frames through a pool of their own
    # The header stamps of the last messages put, for the service's stamps queryable.
    stamps: deque[Stamp] = field(default_factory=lambda: deque(maxlen=STAMPS_KEPT))

    def put(self, message: M) -> None:
        if self.frames is not None and image_field(type(message)) is not None:
            self.publisher.put(self.frames.payload(frame_parts(message)))
        else:
            self.publisher.put(encode(message))
        self.meter.tick()
        header = getattr(message, "header", None)
        if isinstance(header, Header):
            self.stamps.append((header.frame_seq, header.recv_time_s, header.send_time_s))


def typed_publisher(
    session: zenoh.Session, key: str, block: bool = True, frames: bool = False
) -> TypedPublisher[Any]:
    """A :class:`TypedPublisher` on ``key`` (see :meth:`Node.publisher` for the options)."""
    cc = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
    writer = ShmFrameWriter() if frames and shm_enabled() else None
    return TypedPublisher(key, session.declare_publisher(key, congestion_control=cc), frames=writer)


class Node:
    """One service: a Zenoh session, typed pub/sub, a status queryable, a liveliness token.

    ``status_fields`` returns the service-specific part of the status answer.
    """

    def __init__(
        self,
        service: str,
        keys: Keys,
        session: zenoh.Session,
        status_fields: Callable[[], dict[str, Any]] = dict,
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
        self._cond = threading.Condition()
        # (key, message, wall-clock receive time): the time goes into the headers of what
        # handling the message publishes (Header.recv_time_s), for per-hop latency.
        self._inbox: deque[tuple[str, BaseModel, float]] = deque()
        self.event_recv_time_s = 0.0  # receive time of the event next_event returned last
        self._handling_recv_time_s = 0.0  # ... while spin() handles it, else 0
        self._latest_only: set[str] = set()
        self._publishers: dict[str, TypedPublisher[Any]] = {}
        self._subscribers: list[Any] = []
        self.received: dict[str, TopicMeter] = {}
        self.rejected = 0
        self.last_rejection = ""
        self._last_reject_log = 0.0
        self._closed = False
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
        self._token = self.session.liveliness().declare_token(self.keys.alive(self.service))

    # --- publishing -------------------------------------------------------------------
    def publisher(self, key: str, block: bool = True, frames: bool = False) -> TypedPublisher[Any]:
        """``block``: back-pressure instead of dropping when the network is congested.
        ``frames``: camera frames, written into a shared-memory pool (:class:`ShmFrameWriter`)
        unless shared memory is off."""
        pub = typed_publisher(self.session, key, block, frames)
        self._publishers[key] = pub
        return pub

    def header(self, sim_time_s: float, frame_seq: int, recv_time_s: float | None = None) -> Header:
        """A fresh header: per-node sequence number, wall-clock send time, and the receive time
        of the event being handled by :meth:`spin` (0 outside one) unless ``recv_time_s``."""
        recv = self._handling_recv_time_s if recv_time_s is None else recv_time_s
        h = Header(
            seq=self._seq,
            sim_time_s=sim_time_s,
            send_time_s=time.time(),
            frame_seq=frame_seq,
            recv_time_s=recv,
        )
        self._seq += 1
        return h

    # --- subscribing ------------------------------------------------------------------
    def subscribe(
        self,
        key: str,
        model: type[M],
        max_bytes: int = DEFAULT_MAX_BYTES,
        latest_only: bool = False,
    ) -> None:
        """Deliver validated ``model`` messages on ``key`` to :meth:`next_event`.

        ``latest_only``: an undelivered older message on the same key is replaced (and counted
        as dropped), so a slow consumer always works on the newest data.
        """
        meter = self.received[key] = TopicMeter()
        if latest_only:
            self._latest_only.add(key)

        def on_sample(sample: zenoh.Sample) -> None:
            received = time.time()  # before the copy and decode: those count as processing
            payload = sample.payload
            via_shm = payload.as_shm() is not None  # 0.2 µs; diagnostics (status, umay bench)
            try:
                message = decode(payload.to_bytes(), model, max_bytes)
            except MessageError as exc:
                self._reject(key, str(exc))
                return
            with self._cond:
                meter.tick()
                meter.shm += via_shm
                if key in self._latest_only:
                    for i, (k, _, _) in enumerate(self._inbox):
                        if k == key:
                            del self._inbox[i]
                            meter.dropped += 1
                            break
                self._inbox.append((key, message, received))
                self._cond.notify()

        self._subscribers.append(self.session.declare_subscriber(key, on_sample))

    def next_event(self, timeout_s: float | None) -> tuple[str, Any] | None:
        """The next ``(key, message)``, or None after ``timeout_s`` or when closed."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._cond:
            self._loop_waiting = True
            try:
                while not self._inbox and not self._closed:
                    remaining = None if deadline is None else deadline - time.monotonic()
                    if remaining is not None and remaining <= 0:
                        return None
                    self._cond.wait(remaining)
                if not self._inbox:
                    return None
                key, message, self.event_recv_time_s = self._inbox.popleft()
                return key, message
            finally:
                self._loop_waiting = False
                self._loop_left_s = time.monotonic()

    def _reject(self, key: str, reason: str) -> None:
        with self._cond:
            self.rejected += 1
            self.last_rejection = f"{key}: {reason}"
        now = time.monotonic()
        if now - self._last_reject_log > 1.0:  # rate-limited: a flood must not flood the log
            self._last_reject_log = now
            log.warning(
                "%s rejected a message (%d so far): %s", self.service, self.rejected, reason
            )

    # --- status -----------------------------------------------------------------------
    def status(self) -> ServiceStatus:
        now = time.monotonic()
        reason = self._degraded_reason() if self.state == "running" else ""
        p50, p99 = self.processing.percentiles()
        return ServiceStatus(
            service=self.service,
            pid=os.getpid(),
            host=socket.gethostname(),
            uptime_s=now - self._started,
            state="degraded" if reason else self.state,  # type: ignore[arg-type]
            degraded_reason=reason,
            received={k: m.stats(now) for k, m in self.received.items()},
            published={k: p.meter.stats(now) for k, p in self._publishers.items()},
            rejected=self.rejected,
            last_rejection=self.last_rejection,
            processing_ms_p50=p50,
            processing_ms_p99=p99,
            loop_busy_s=self.loop_busy_s(now),
            fields=self._status_fields(),
        )

    def loop_busy_s(self, now_s: float) -> float | None:
        """Seconds since the event loop left :meth:`next_event` (0 while it is inside)."""
        left = self._loop_left_s
        if left is None:
            return None
        return 0.0 if self._loop_waiting else max(0.0, now_s - left)

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
        """The node's one event loop: announce readiness, handle events until ``stop``, close.

        ``on_idle`` runs after every wake-up (an event or ``timeout_s`` without one).
        """
        self.ready()
        try:
            while not stop.is_set():
                event = self.next_event(timeout_s)
                if event is not None:
                    started = time.perf_counter()
                    self._handling_recv_time_s = self.event_recv_time_s
                    try:
                        on_event(*event)
                    finally:
                        self._handling_recv_time_s = 0.0
                    self.processing.add(1000.0 * (time.perf_counter() - started))
                if on_idle is not None:
                    on_idle()
        finally:
            self.close()

    def close(self) -> None:
        self.state = "stopping"
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        for s in self._subscribers:
            s.undeclare()
        self._queryable.undeclare()
        self._stamps_queryable.undeclare()
        if self._token is not None:
            self._token.undeclare()
        self.session.close()


def status_from_reply(reply: zenoh.Reply) -> ServiceStatus | None:
    """The status in a reply to a status query; None for an error reply. MessageError when
    the payload is not a valid status."""
    if reply.ok is None:
        return None
    return decode(reply.ok.payload.to_bytes(), ServiceStatus, DEFAULT_MAX_BYTES)


def query_status(session: zenoh.Session, keys: Keys, timeout_s: float = 1.0) -> list[ServiceStatus]:
    """Ask every service under ``keys.prefix`` for its status."""
    out = []
    for reply in session.get(keys.all_status, timeout=timeout_s):
        try:
            status = status_from_reply(reply)
        except MessageError as exc:
            log.warning("bad status reply: %s", exc)
            continue
        if status is not None:
            out.append(status)
    return out


def query_stamps(
    session: zenoh.Session, keys: Keys, service: str, timeout_s: float = 2.0
) -> PublishedStamps | None:
    """``service``'s :class:`PublishedStamps`, or None when it does not answer in time."""
    for reply in session.get(keys.stamps(service), timeout=timeout_s):
        if reply.ok is not None:
            return decode(reply.ok.payload.to_bytes(), PublishedStamps, STAMPS_MAX_BYTES)
    return None


def setup_logging(service: str) -> None:
    logging.basicConfig(
        level=os.environ.get("UMAY_LOG_LEVEL", "INFO"),
        format=f"%(asctime)s {service} %(levelname)s %(message)s",
    )


def alive_services(session: zenoh.Session, keys: Keys, timeout_s: float = 1.0) -> set[str]:
    """Services whose liveliness token is present under ``keys.prefix``."""
    names = set()
    for reply in session.liveliness().get(keys.all_alive, timeout=timeout_s):
        if reply.ok is not None:
            names.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
    return names
