"""A small Foxglove WebSocket client: what the Foxglove app does when it connects, for the
tests and ``umay bench --view`` (a real client on a real socket, not a mock).

It speaks the protocol the SDK's server speaks (subprotocol ``foxglove.sdk.v1``, the older
``foxglove.websocket.v1`` offered too): reads ``serverInfo`` and ``advertise``, subscribes to
the advertised channels it wants, and collects the binary ``messageData`` frames
(opcode 1, u32 subscription id, u64 log time in ns, payload). :func:`decoder` turns a
payload into a message with the schema the server advertised (protobuf from its descriptor
set, or JSON).
"""

from __future__ import annotations

import asyncio
import base64
import json
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
MESSAGE_DATA = 1  # binary opcode of a data message
TIME = 2  # binary opcode of a server time message
_DATA_HEADER = struct.Struct("<BIQ")


@dataclass
class Received:
    topic: str
    log_time_ns: int
    payload: bytes


@dataclass
class FoxgloveClient:
    """Connects in a thread of its own. ``topics``: the topics to subscribe to (None: all
    advertised). ``keep``: keep the payloads (else only count them). ``paused``: while set,
    nothing is read from the socket (a slow client: the server's queue for it fills)."""

    url: str
    topics: set[str] | None = None
    keep: bool = True
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)  # advertised, by id
    received: list[Received] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    server_info: dict[str, Any] | None = None
    subprotocol: str | None = None
    error: BaseException | None = None
    server_time_ns: int | None = None
    paused: threading.Event = field(default_factory=threading.Event)
    _stop: threading.Event = field(default_factory=threading.Event)
    _subscribed: dict[int, str] = field(default_factory=dict)  # subscription id → topic
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _thread: threading.Thread | None = None

    def start(self) -> FoxgloveClient:
        self._thread = threading.Thread(target=self._run, daemon=True, name="foxglove-client")
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        self.paused.clear()
        if self._thread is not None:
            self._thread.join(timeout_s)

    def wait_for(self, predicate: Callable[[FoxgloveClient], bool], timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.error is not None:
                raise self.error
            with self._lock:
                if predicate(self):
                    return True
            time.sleep(0.05)
        return False

    def messages(self, topic: str) -> list[Received]:
        with self._lock:
            return [r for r in self.received if r.topic == topic]

    def channel(self, topic: str) -> dict[str, Any]:
        return next(c for c in self.channels.values() if c["topic"] == topic)

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # reported to the caller through wait_for
            if not self._stop.is_set():
                self.error = exc

    async def _main(self) -> None:
        import websockets

        async with websockets.connect(
            self.url, subprotocols=list(SUBPROTOCOLS), max_size=None, max_queue=16
        ) as ws:
            self.subprotocol = ws.subprotocol
            next_id = 1
            while not self._stop.is_set():
                if self.paused.is_set():
                    await asyncio.sleep(0.05)
                    continue
                try:
                    raw = await asyncio.wait_for(ws.recv(), 0.2)
                except TimeoutError:
                    continue
                if isinstance(raw, str):
                    next_id = await self._on_text(ws, json.loads(raw), next_id)
                else:
                    self._on_binary(raw)

    async def _on_text(self, ws: Any, msg: dict[str, Any], next_id: int) -> int:
        op = msg.get("op")
        if op == "serverInfo":
            self.server_info = msg
        elif op == "advertise":
            subs = []
            for ch in msg["channels"]:
                self.channels[ch["id"]] = ch
                if self.topics is None or ch["topic"] in self.topics:
                    subs.append({"id": next_id, "channelId": ch["id"]})
                    self._subscribed[next_id] = ch["topic"]
                    next_id += 1
            if subs:
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
        elif op == "unadvertise":
            for cid in msg.get("channelIds", []):
                self.channels.pop(cid, None)
        return next_id

    def _on_binary(self, raw: bytes) -> None:
        if raw[0] == TIME:
            self.server_time_ns = struct.unpack_from("<Q", raw, 1)[0]
            return
        if raw[0] != MESSAGE_DATA:
            return
        _op, sub, log_time = _DATA_HEADER.unpack_from(raw, 0)
        topic = self._subscribed.get(sub)
        if topic is None:
            return
        with self._lock:
            self.counts[topic] = self.counts.get(topic, 0) + 1
            if self.keep:
                self.received.append(Received(topic, log_time, raw[_DATA_HEADER.size :]))


def protobuf_class(schema_name: str, descriptor_set: bytes) -> Any:
    """The message class of ``schema_name`` from a serialized FileDescriptorSet (what a
    protobuf channel's schema is, in MCAP and, base64-encoded, in an ``advertise``)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set)
    pool = descriptor_pool.DescriptorPool()
    for f in files.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def decoder(channel: dict[str, Any]) -> Callable[[bytes], Any]:
    """Payload → message for an advertised channel: a protobuf message, or a dict (JSON)."""
    if channel["encoding"] == "json":
        return json.loads
    if channel["encoding"] == "protobuf":
        cls = protobuf_class(channel["schemaName"], base64.b64decode(channel["schema"]))
        return cls.FromString
    raise ValueError(f"{channel['topic']}: no decoder for encoding {channel['encoding']!r}")
