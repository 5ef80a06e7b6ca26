"""``umay export RUN.mcap --foxglove OUT.mcap``: a project recording as an MCAP file that
Foxglove shows (images with overlays, the moving arm, the plots).

The project's recordings keep the wire payloads (message encodings ``msgpack`` and
``umay-frame``, which no viewer decodes); this writes the live view's channels instead, in
the same schemas, converted by the same functions (:mod:`deploy.foxglove.convert`), with log
times from the simulation. Every frame is converted (no rate limit, unlike the live view).
The recording itself is left as it is: replay needs it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import foxglove

from common.codec import FRAME_MAX_BYTES, MessageError, decode
from common.config import Scenario
from deploy.foxglove import convert
from deploy.foxglove.channels import FoxgloveChannels
from deploy.recording.channels import METADATA_NAME, split_data_key
from deploy.recording.read import RecordingReader, recorded_scenario

# A recording that spans a sim restart holds runs that each begin at 0 s simulated: exported,
# each later run follows the one before by this much, on one timeline.
RUN_GAP_S = 1.0


@dataclass
class ExportReport:
    written: dict[str, int] = field(default_factory=dict)  # per Foxglove topic
    skipped: int = 0  # recorded messages the view does not show (timing)
    rejected: int = 0  # recorded payloads that do not decode
    notes: list[str] = field(default_factory=list)
    runs: int = 1  # the sim's runs in the recording (Header.run, or simulated time going back)


def shifted(message: Any, offset_s: float) -> Any:
    """``message`` with its header's simulated time moved by ``offset_s`` (the same message
    for 0); messages without a header as they are."""
    header = getattr(message, "header", None)
    if not offset_s or header is None:
        return message
    moved = header.model_copy(update={"sim_time_s": header.sim_time_s + offset_s})
    return message.model_copy(update={"header": moved})


def export_foxglove(recording: str | Path, out: str | Path, jpeg_quality: int = 85) -> ExportReport:
    """Write ``out`` from ``recording`` (through a file beside it, renamed once complete: an
    export cut short, or with nothing to show, leaves no file that passes for one); raises
    NotARecordingError for a file that is not MCAP, ScenarioError for a recorded scenario that
    does not load."""
    reader = RecordingReader(recording)
    scenario, notes = recorded_scenario(reader)
    out = Path(out)
    partial = out.with_name(f".{out.name}.partial")
    try:
        report = _export(reader, scenario, partial, jpeg_quality, notes)
        if report.written:
            partial.replace(out)
    finally:
        partial.unlink(missing_ok=True)
    return report


def _export(
    reader: RecordingReader, scenario: Scenario, out: Path, jpeg_quality: int, notes: list[str]
) -> ExportReport:
    recording = reader.path
    report = ExportReport(notes=notes)
    state = convert.ViewState(scenario)
    offset_s = 0.0  # added to the current run's simulated time
    context = foxglove.Context()
    channels = FoxgloveChannels(context)
    with foxglove.open_mcap(str(out), allow_overwrite=True, context=context) as writer:
        meta = reader.metadata().get(METADATA_NAME, {})
        writer.write_metadata(
            "umay_export",
            {"source": str(recording), "prefix": meta.get("prefix", ""), "time": "simulation"},
        )
        for _schema, channel, message in reader.messages():
            split = split_data_key(channel.topic)
            if split is None or split[1] not in convert.VIEWED_KEYS:
                report.skipped += 1
                continue
            _prefix, suffix, model = split
            try:
                msg = decode(message.data, model, FRAME_MAX_BYTES)
            except MessageError:
                report.rejected += 1
                continue
            # A recording can span runs (the sim restarted): each gets its own view, as live,
            # and follows the one before on the timeline.
            moved = shifted(msg, offset_s)
            fresh = state.continued(moved)
            if fresh is None:  # logged late, after the sim restarted
                report.skipped += 1
                continue
            if fresh is not state:
                report.runs += 1
                offset_s = state.sim_time_s + RUN_GAP_S - msg.header.sim_time_s
                moved, state = shifted(msg, offset_s), fresh
            for o in state.on_message(suffix, moved, jpeg_quality):
                channels.log(o)
                report.written[o.topic] = report.written.get(o.topic, 0) + 1
    channels.close()
    if report.runs > 1:
        report.notes.append(
            f"the recording holds {report.runs} runs of the sim: each exported from its own "
            f"start, {RUN_GAP_S:g} s after the end of the one before"
        )
    if reader.damage:
        report.notes.append(f"recording {reader.damage}")
    return report
