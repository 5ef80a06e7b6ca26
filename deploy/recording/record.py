"""Record the system's traffic to MCAP (read back by :mod:`deploy.recording.read`).

One MCAP channel per key (topic = the Zenoh key), the payload bytes exactly as they travelled
(message encoding ``msgpack``; camera frames ``umay-frame``: a msgpack header and the raw
pixels, see :mod:`common.codec`), the pydantic JSON schema of the key's model as the channel
schema (encoding ``jsonschema``), receive time as ``log_time`` and the header's
``send_time_s`` as ``publish_time``; zstd-compressed chunks with a summary and indexes, so
Foxglove Studio, the ``mcap`` CLI and :mod:`deploy.recording.replay` can all read it.

Camera frames are always stored whole: a frame the sim sent by reference (a descriptor of a
slot in its shared-memory ring, see :mod:`common.publishers`) is turned back into the ordinary
layout as it arrives, from the ring when this host maps it, else by asking the sim for the
whole frame, so a recording, and its replay, never depend on a ring that is long gone. A frame
that could be had neither way (overwritten, the sim gone) is counted in
:attr:`Recorder.lost`, with the reason. A recording ``without_frames`` leaves the camera frames
out altogether (counted in :attr:`Recorder.frames_left_out`, and said in the metadata): what
``umay plot`` and the live view's scene need is a few hundred kilobytes where the frames are
megabytes a second, small enough to keep beside a study's figures.

Metadata record ``umay`` holds what a replay needs: the scenario TOML text
(``scenario_toml``), the ``--set`` overrides as a JSON list (``overrides_json``) and the key
prefix (``prefix``).
"""

from __future__ import annotations

import contextlib
import json
import threading
import time
from pathlib import Path
from typing import IO

import zenoh
from mcap.writer import CompressionType, Writer
from pydantic import BaseModel

from common import codec
from common.config import DEFAULT_SCENARIO
from common.frame_ring import RingReader
from common.keys import Keys
from common.publishers import fetch_whole_frame
from deploy.recording.channels import (
    FRAME_MESSAGE_ENCODING,
    MESSAGE_ENCODING,
    METADATA_NAME,
    PROFILE,
    SCHEMA_ENCODING,
    model_for_key,
    split_data_key,
)

# A chunk is compressed and written once this many bytes of messages are in it: what a
# recorder killed outright loses at most (a camera frame fills one alone; small messages
# alone, 30 twists a second, fill one in a few seconds: at 1 MiB, over a minute was lost).
CHUNK_BYTES = 64 << 10


def run_metadata(
    scenario_path: str | Path | None, overrides: list[str], prefix: str
) -> dict[str, str]:
    """What a replay needs to start a service as it ran: the scenario file's text (the default
    scenario when None), the ``--set`` overrides and the prefix."""
    path = Path(scenario_path) if scenario_path else DEFAULT_SCENARIO
    return {
        "scenario_toml": path.read_text(),
        "scenario_path": str(scenario_path) if scenario_path else "(default scenario)",
        "overrides_json": json.dumps(list(overrides)),
        "prefix": prefix,
    }


def _send_time_ns(payload: bytes) -> int | None:
    """The header's ``send_time_s`` in ns, or None if the payload has no readable header."""
    try:
        return round(float(codec.unpack(payload)["header"]["send_time_s"]) * 1e9)  # type: ignore[index]
    except Exception:  # not a message, no header: recorded anyway, the wire is what it is
        return None


class Recorder:
    """Subscribe to ``key_expr`` (default: everything under the prefix) and write every data
    message to an MCAP file, made at the first message. Thread-safe: Zenoh calls back from
    several threads.

    Use as a context manager, or call :meth:`close` to finish the file (summary, indexes).
    """

    def __init__(
        self,
        path: str | Path,
        session: zenoh.Session,
        keys: Keys,
        key_expr: str | None = None,
        metadata: dict[str, str] | None = None,
        chunk_size: int = CHUNK_BYTES,
        rings: RingReader | None = None,
        without_frames: bool = False,
    ) -> None:
        """``rings``: what maps the sim's ring for frames sent by reference (default: the
        process's :func:`~common.frame_ring.shared_reader`); ``without_frames``: leave the
        camera frames out."""
        self.path = Path(path)
        self.without_frames = without_frames
        self.frames_left_out = 0
        self._rings = rings
        self.keys = keys
        self.key_expr = key_expr or f"{keys.prefix}/**"
        self.counts: dict[str, int] = {}
        self.skipped = 0  # samples on keys without a model
        self.lost = 0  # frames by reference that could not be had whole
        self.last_loss = ""
        self._session = session
        self._lock = threading.Lock()
        self._closed = False
        self._channels: dict[str, int] = {}
        self._schemas: dict[type[BaseModel], int] = {}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._chunk_size = chunk_size
        self._metadata = {k: str(v) for k, v in (metadata or {}).items()}
        if without_frames:
            self._metadata["frames"] = "left out"
        # The file is made at the first message (_writer_at_first): a recorder that hears
        # nothing leaves no file, and does not empty one already at its path.
        self._stream: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._subscriber = session.declare_subscriber(self.key_expr, self._on_sample)

    def _writer_at_first(self) -> Writer:
        """The MCAP writer, the file opened and started at the first call. With the lock held."""
        if self._writer is None:
            self._stream = self.path.open("wb")
            self._writer = Writer(
                self._stream, chunk_size=self._chunk_size, compression=CompressionType.ZSTD
            )
            self._writer.start(profile=PROFILE, library="umay deploy.recording")
            if self._metadata:
                self._writer.add_metadata(METADATA_NAME, self._metadata)
            # What the writer has written (the header, the metadata, then each finished chunk)
            # goes to the file at once, for a recorder killed outright to leave behind.
            self._stream.flush()
        return self._writer

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def _model(self, key: str) -> type[BaseModel] | None:
        model = model_for_key(self.keys, key)
        if model is None:  # a wider key expression: another prefix
            split = split_data_key(key)
            model = split[2] if split else None
        return model

    def _channel(self, writer: Writer, key: str, model: type[BaseModel]) -> int:
        """Called with the lock held."""
        channel = self._channels.get(key)
        if channel is None:
            schema = self._schemas.get(model)
            if schema is None:
                schema = writer.register_schema(
                    name=model.__name__,
                    encoding=SCHEMA_ENCODING,
                    data=json.dumps(model.model_json_schema()).encode(),
                )
                self._schemas[model] = schema
            encoding = FRAME_MESSAGE_ENCODING if codec.image_field(model) else MESSAGE_ENCODING
            channel = writer.register_channel(
                topic=key, message_encoding=encoding, schema_id=schema
            )
            self._channels[key] = channel
            self.counts[key] = 0
        return channel

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        model = self._model(key)
        if model is None:
            with self._lock:
                self.skipped += 1
            return
        is_frame = codec.image_field(model) is not None
        if is_frame and self.without_frames:
            with self._lock:
                self.frames_left_out += 1
            return
        payload = sample.payload.to_bytes()
        if is_frame and codec.is_by_reference(payload):
            try:
                payload = codec.whole_frame(payload, model, self._rings)
            except codec.FrameUnreachable as exc:  # not on this host: ask the sim
                fetch_whole_frame(
                    self._session,
                    key,
                    exc.ref,
                    lambda whole: self._write(key, model, whole),
                    lambda reason: self._lose(key, reason),
                )
                return
            except codec.MessageError as exc:
                self._lose(key, str(exc))
                return
        self._write(key, model, payload)

    def _lose(self, key: str, reason: str) -> None:
        with self._lock:
            self.lost += 1
            self.last_loss = f"{key}: {reason}"

    def _write(self, key: str, model: type[BaseModel], payload: bytes) -> None:
        sent_ns = _send_time_ns(payload)
        with self._lock:
            if self._closed:
                return
            now_ns = time.time_ns()  # taken under the lock: log times follow the file order
            writer = self._writer_at_first()
            channel = self._channel(writer, key, model)
            writer.add_message(
                channel_id=channel,
                log_time=now_ns,
                data=payload,
                publish_time=now_ns if sent_ns is None else sent_ns,
                sequence=self.counts[key],
            )
            assert self._stream is not None
            self._stream.flush()  # a no-op until the writer finishes a chunk
            self.counts[key] += 1

    def message_counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self.counts)

    def close(self) -> None:
        """Stop listening and finish the file (summary and indexes); idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        with contextlib.suppress(Exception):  # the session may already be closed
            self._subscriber.undeclare()
        with self._lock:
            if self._writer is not None and self._stream is not None:
                self._writer.finish()
                self._stream.close()
