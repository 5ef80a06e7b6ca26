"""Read a recording back, complete or cut short: its messages, its metadata, and the summary
``umay info`` prints (channels, counts, rates, time spans). Written by
:mod:`deploy.recording.record`; what its channels hold is :mod:`deploy.recording.channels`."""

from __future__ import annotations

import contextlib
import json
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Message, Schema
from mcap.summary import Summary
from mcap.writer import MCAP0_MAGIC
from pydantic import BaseModel

from common import codec
from common.config import DEFAULT_SCENARIO, Scenario, ScenarioError, load_scenario
from common.runtime import parse_overrides
from deploy.recording.channels import METADATA_NAME


class ChannelInfo(BaseModel):
    topic: str
    schema_name: str
    message_encoding: str
    count: int
    rate_hz: float | None  # None with fewer than two messages
    first_time_s: float | None  # log time, Unix s
    last_time_s: float | None


class RecordingInfo(BaseModel):
    path: str
    size_bytes: int
    profile: str
    channels: list[ChannelInfo]
    message_count: int
    start_time_s: float | None
    end_time_s: float | None
    duration_s: float
    compression: list[str]
    chunk_count: int | None  # None: not known (a file cut short has no summary to list them)
    metadata: dict[str, dict[str, str]]
    damage: str | None = None  # a file cut short or damaged: how much of it was read


class NotARecordingError(ValueError):
    """The file is not MCAP at all (a recording cut short still starts as one)."""


class RecordingReader:
    """Reads a recording, complete or cut short.

    A complete recording is read through its summary and indexes. One cut short (its
    recorder killed, the disk full: no summary, no footer, a last chunk half written) is read
    linearly up to the damage, and :attr:`damage` says where reading stopped and why, so
    ``info``, ``plot`` and ``replay`` keep what was recorded instead of refusing it all. A file
    that is not MCAP raises :class:`NotARecordingError`.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if self.path.is_dir():
            raise NotARecordingError(f"{self.path}: a folder, not a recording")
        with self.path.open("rb") as f:
            if f.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
                raise NotARecordingError(
                    f"{self.path}: not an MCAP recording (no MCAP magic at its start)"
                )
            f.seek(0)
            try:
                self.header = NonSeekingReader(f).get_header()
            except Exception as exc:  # EndOfFile, or a damaged header record
                raise NotARecordingError(
                    f"{self.path}: an MCAP file cut short before its header ended (a recorder "
                    f"killed as it started?): {type(exc).__name__}"
                ) from exc
            f.seek(0)
            try:
                self.summary: Summary | None = make_reader(f).get_summary()
            except Exception:  # mcap raises several types: a damaged or missing footer
                self.summary = None
        self.damage: str | None = None  # why a scan stopped before the end, once one has

    def messages(
        self, select: Callable[[str], bool] | None = None, log_time_order: bool = True
    ) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """The messages of the topics ``select`` accepts (all by default)."""
        with self.path.open("rb") as f:
            if self.summary is not None:
                topics = [c.topic for c in self.summary.channels.values()]
                wanted = [t for t in topics if select is None or select(t)]
                if wanted:
                    records = make_reader(f).iter_messages(wanted, log_time_order=log_time_order)
                    yield from self._until_damage(records)
                return
            # As written, which is log-time order: the recorder takes each message's log time
            # under the lock it writes with (record.py). Sorting would hold the whole file.
            records = NonSeekingReader(f).iter_messages(log_time_order=False)
            for record in self._until_damage(records):
                if select is None or select(record[1].topic):
                    yield record

    def _until_damage(self, records: Iterator[Any]) -> Iterator[Any]:
        count = 0
        try:
            for record in records:
                count += 1
                yield record
        except EndOfFile:
            self._damaged(count, "then the file ends inside a record")
        except Exception as exc:  # mcap raises several types on a damaged record
            self._damaged(count, f"then a damaged record ({type(exc).__name__}: {exc})")

    def _damaged(self, count: int, then: str) -> None:
        where = "cut short (no summary)" if self.summary is None else "damaged"
        self.damage = f"{where}: {count} messages read, {then}"

    def metadata(self) -> dict[str, dict[str, str]]:
        """The metadata records (the recorder writes them first, so a cut file keeps them)."""
        found: dict[str, dict[str, str]] = {}
        with self.path.open("rb") as f:
            reader = make_reader(f) if self.summary is not None else NonSeekingReader(f)
            with contextlib.suppress(Exception):  # the damage ends the metadata too
                for m in reader.iter_metadata():
                    found[m.name] = dict(m.metadata)
        return found

    def topics(self) -> list[str]:
        if self.summary is not None:
            return sorted(c.topic for c in self.summary.channels.values())
        return sorted({channel.topic for _s, channel, _m in self.messages(log_time_order=False)})


def read_info(path: str | Path) -> RecordingInfo:
    """Channels with counts, rates and time spans, the duration and the metadata; of a
    recording cut short, what precedes the damage (:attr:`RecordingInfo.damage` says so)."""
    reader = RecordingReader(path)
    summary = reader.summary
    channels_by_id: dict[int, Channel] = dict(summary.channels) if summary else {}
    schemas: dict[int, Schema] = dict(summary.schemas) if summary else {}
    first: dict[int, int] = {}
    last: dict[int, int] = {}
    counts: dict[int, int] = {}
    # In log-time order where there is an index: mcap's indexed reader streams chunk by chunk
    # then, but decompresses every chunk before the first message when asked for file order
    # (a 301 MB recording took 3.9 GB).
    for schema, channel, message in reader.messages(log_time_order=summary is not None):
        cid = channel.id
        channels_by_id.setdefault(cid, channel)
        if schema is not None:
            schemas.setdefault(schema.id, schema)
        t = message.log_time
        first[cid] = min(first.get(cid, t), t)
        last[cid] = max(last.get(cid, t), t)
        counts[cid] = counts.get(cid, 0) + 1
    channels = []
    for cid, ch in sorted(channels_by_id.items(), key=lambda c: c[1].topic):
        n = counts.get(cid, 0)
        t0, t1 = first.get(cid), last.get(cid)
        span = (t1 - t0) / 1e9 if t0 is not None and t1 is not None else 0.0
        schema = schemas.get(ch.schema_id)
        channels.append(
            ChannelInfo(
                topic=ch.topic,
                schema_name=schema.name if schema else "",
                message_encoding=ch.message_encoding,
                count=n,
                rate_hz=(n - 1) / span if n > 1 and span > 0 else None,
                first_time_s=None if t0 is None else t0 / 1e9,
                last_time_s=None if t1 is None else t1 / 1e9,
            )
        )
    starts = [c.first_time_s for c in channels if c.first_time_s is not None]
    ends = [c.last_time_s for c in channels if c.last_time_s is not None]
    chunks = summary.chunk_indexes if summary else []
    return RecordingInfo(
        path=str(reader.path),
        size_bytes=reader.path.stat().st_size,
        profile=reader.header.profile,
        channels=channels,
        message_count=sum(c.count for c in channels),
        start_time_s=min(starts) if starts else None,
        end_time_s=max(ends) if ends else None,
        duration_s=(max(ends) - min(starts)) if starts else 0.0,
        compression=sorted({c.compression or "none" for c in chunks}),
        chunk_count=len(chunks) if summary else None,
        metadata=reader.metadata(),
        damage=reader.damage,
    )


def format_info(info: RecordingInfo) -> str:
    """A readable summary: file, duration, one line per channel, the metadata."""

    def when(t: float | None) -> str:
        if t is None:
            return "-"
        return time.strftime("%H:%M:%S", time.localtime(t)) + f".{int(t % 1 * 1000):03d}"

    lines = [
        f"file         {info.path} ({info.size_bytes / 1e6:.2f} MB)",
        f"duration     {info.duration_s:.3f} s  ({when(info.start_time_s)} → "
        f"{when(info.end_time_s)})",
        f"messages     {info.message_count} in {len(info.channels)} channels, "
        + (
            "chunks not known (no summary)"
            if info.chunk_count is None
            else f"{info.chunk_count} chunks ({', '.join(info.compression) or 'none'})"
        ),
        *([f"warning      {info.damage}"] if info.damage else []),
        "",
    ]
    width = max([len(c.topic) for c in info.channels] + [5])
    lines.append(f"{'topic':<{width}}  {'schema':<20} {'count':>7} {'rate Hz':>8}  first → last")
    for c in info.channels:
        rate = "-" if c.rate_hz is None else f"{c.rate_hz:.2f}"
        lines.append(
            f"{c.topic:<{width}}  {c.schema_name:<20} {c.count:>7} {rate:>8}  "
            f"{when(c.first_time_s)} → {when(c.last_time_s)}"
        )
    for name, meta in info.metadata.items():
        lines.append("")
        lines.append(f"metadata {name}:")
        for k, v in meta.items():
            text = v if "\n" not in v else f"({len(v.splitlines())} lines)"
            lines.append(f"  {k}: {text}")
    return "\n".join(lines)


def iter_messages(
    path: str | Path, topics: list[str] | None = None
) -> Iterator[tuple[str, int, int, bytes]]:
    """``(topic, log_time_ns, publish_time_ns, payload)`` in log-time order."""
    wanted = None if topics is None else set(topics).__contains__
    for _schema, channel, message in RecordingReader(path).messages(wanted):
        yield channel.topic, message.log_time, message.publish_time, message.data


def unpack(payload: bytes) -> dict[str, Any]:
    """A recorded payload as plain data (no validation; a camera frame without its pixels)."""
    data = codec.unpack(payload)
    if data is None:
        raise ValueError("not a message payload")
    return data


def recorded_scenario(reader: RecordingReader) -> tuple[Scenario, list[str]]:
    """The scenario the recording ran (its metadata), with its overrides; the default one
    (with a note) when it holds none."""
    meta = reader.metadata().get(METADATA_NAME, {})
    try:
        overrides = [str(o) for o in json.loads(meta.get("overrides_json", "[]"))]
    except (ValueError, TypeError) as exc:  # written by another tool, or damaged
        raise ScenarioError(f"{reader.path}: its metadata's overrides_json: {exc}") from exc
    notes = []
    text = meta.get("scenario_toml")
    if not text:
        notes.append("the recording holds no scenario: the default one was used")
        return load_scenario(DEFAULT_SCENARIO, parse_overrides(overrides)), notes
    with tempfile.TemporaryDirectory(prefix="umay-export-") as tmp:
        path = Path(tmp) / "scenario.toml"
        path.write_text(text)
        return load_scenario(path, parse_overrides(overrides)), notes
