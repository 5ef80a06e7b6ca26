"""``umay bench``'s report as typed models: each part's figures, one run, the medians of runs,
and the JSON written (``umay bench --json``, read back by ``umay docs`` from docs/bench/).

A model's fields are the JSON's keys in the order they are written. What a run needs only to
compare the in-process commands with the distributed ones (``velocities``) travels in fields
excluded from the JSON; what exists only in some reports (a run's frame rows, the medians'
pooled tail and largest drops) is left out of the JSON when it is absent.
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    model_serializer,
)

JSON_VERSION = 1
LATENCY_GOAL_MS = 10.0  # issue 7's goal for the p99 at 640×480: frames over it are counted

# One frame's row: its frame_seq, its latency and its stages (ms), for the figure.
FrameRow = dict[str, int | float]
# frame_seq → the joint velocities (rad/s) of that frame's command; None: not heard of.
Velocities = dict[int, list[float] | None]


def _absent(v: object) -> bool:
    return v is None


def _omitted_when_absent() -> Any:
    """A field left out of the JSON when it holds None (a key only some reports have)."""
    return Field(default=None, exclude_if=_absent)


class Figures(BaseModel):
    """A part of the report: its keys are fixed, a file with another key does not load."""

    model_config = ConfigDict(extra="forbid")


class Percentiles(Figures):
    """n, p50, p99 and max of durations in milliseconds (the renderers' and the model's)."""

    n: int
    p50: float
    p99: float
    max: float


class Summary(Figures):
    """n, p50, p99, max and mean of durations in milliseconds; None when there were none."""

    n: int
    p50: float | None
    p99: float | None
    max: float | None
    mean: float | None


class ServiceUsage(Figures):
    """A service process's CPU time (in total and during the measured window) and memory."""

    pid: int
    cpu_s: float | None
    window_cpu_s: float | None
    cpu_ms_per_frame: float | None
    peak_rss_mb: float | None  # VmHWM
    rss_mb: float | None  # VmRSS
    rss_shmem_mb: float | None  # RssShmem: shared memory pages (Zenoh's pool) in the RSS


class KeyCounts(Figures):
    """What a service received on one key: messages, drops, frames by reference or copy."""

    count: int
    dropped: int
    by_ref: int
    by_copy: int
    fetched: int


class ServiceCounters(Figures):
    """A service's own counters, as its status reports them after the run."""

    received: dict[str, KeyCounts]
    rejected: int
    processing_ms_p50: float | None
    processing_ms_p99: float | None


class Pooled(Figures):
    """The tail over every frame of several runs together (a p99 of one run's few dozen frames
    is its slowest frame or two)."""

    latency_ms: Summary
    frames_over_goal: int
    frame_handoff_ms: Summary


class TraceAnalysis(Figures):
    """What the stamps of a distributed run's measured frames give: per stage, end to end,
    the frame's hand-off (publish + frame_transport), the rate, drops per stage."""

    frames: int
    frames_complete: int
    stages_ms: dict[str, Summary]
    frame_handoff_ms: Summary
    latency_ms: Summary
    frames_over_goal: int
    loop_rate_hz: float | None
    real_time_factor: float | None
    wall_s: float
    dropped: dict[str, int]
    resends: int
    frames_ms: list[FrameRow] | None = _omitted_when_absent()  # the complete frames


class DistributedRun(TraceAnalysis):
    """The four services as processes: the trace's figures and the processes' own."""

    prefix: str
    window: list[int]  # first and last measured frame_seq
    services: dict[str, ServiceUsage]
    status: dict[str, ServiceCounters]
    bench_cpu_s: float
    bench_rejected: int
    frames_by_ref: int | None
    frames_received_by_vision: int | None
    load_before: list[float]
    load_after: list[float]
    observer: dict[str, Any] | None  # the live view's client counts (``--view``)
    # The supervisor's CPU wake-up latency request (deploy.cpu_latency): held, refused, none.
    cpu_wakeup_latency: str | None = _omitted_when_absent()
    pooled: Pooled | None = _omitted_when_absent()  # medians of runs only
    velocities: Velocities = Field(default_factory=dict, exclude=True)  # as the sim applied


class InprocessRun(Figures):
    """The same pipeline in one process: the steps stage by stage, alone and with the codec."""

    frames: int
    stages_ms: dict[str, Summary]
    per_frame_ms: Summary
    per_frame_with_codec_ms: Summary
    frames_ms: list[FrameRow] | None = _omitted_when_absent()
    render_fps: float | None
    load_before: list[float]
    load_after: list[float]
    same_commands_max_abs_diff_rad_s: float | None = None  # lockstep: vs the distributed run
    velocities: Velocities = Field(default_factory=dict, exclude=True)


class SyntheticRun(Figures):
    """Frames replayed at the camera's rate into vision → controller → actuation."""

    rate_hz: float
    frames: int
    distinct_frames: int
    achieved_rate_hz: float | None
    late_publications: int
    stages_ms: dict[str, Summary]
    latency_ms: Summary
    dropped: dict[str, int]
    services: dict[str, ServiceUsage]
    status: dict[str, ServiceCounters]
    load_before: list[float]
    load_after: list[float]


class RendererTimes(Figures):
    requested: str
    renderer: str  # the one the world ended up with
    detail: str
    render_ms: Percentiles


class SensorModelTimes(Figures):
    colour_px: list[int]
    depth_px: list[int]
    colour_ms: Percentiles
    depth_ms: Percentiles
    total_ms: Percentiles


class RenderReport(Figures):
    """The renderers' cost on the same postures and the Kinect model's cost."""

    renderers: dict[str, RendererTimes]
    sensor_model: SensorModelTimes


class ReferenceLoop(Figures):
    """The distributed loop again with the reference renderer."""

    renderer: str
    render_ms: Summary
    latency_ms: Summary
    loop_rate_hz: float | None
    real_time_factor: float | None
    dropped: dict[str, int]


class Machine(Figures):
    host: str
    cpus: int | None
    processor: str
    cpu_model: str | None = None  # model name, family, model: hosts of one class differ
    python: str
    zenoh: str
    load_start: list[float]  # 1, 5 and 15 min load averages
    load_end: list[float]
    code: str | None = None  # the commit measured (git describe; "-dirty": changes on top)

    @model_serializer(mode="wrap")
    def _without_unknown_code(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        # A report made before the code or the CPU model was recorded is written back as it
        # was read.
        data = handler(self)
        for optional in ("code", "cpu_model"):
            if data.get(optional) is None:
                data.pop(optional, None)
        return data


class BenchConfig(Figures):
    width_px: int
    height_px: int
    depth_width_px: int
    depth_height_px: int
    rgb_hz: float
    depth_hz: float
    clock: str
    renderer: str
    transport: str  # shm or tcp
    frames: int
    warmup: int
    controller_mode: str
    view: bool
    overrides: list[str]


class DistributionAdds(Figures):
    """p50 distributed less p50 in-process, and per stage (indicative: medians do not add)."""

    p50: float | None
    parts_p50: dict[str, float | None]


class Ratios(Figures):
    p50: float | None
    p99: float | None
    vs_with_codec_p50: float | None


class BenchReport(Figures):
    """One ``umay bench`` run, or the medians of several (``runs``, ``dropped_max`` and
    ``each_run`` then set)."""

    version: int = JSON_VERSION
    command: str
    machine: Machine
    config: BenchConfig
    distributed: DistributedRun
    inprocess: InprocessRun
    distribution_adds_ms: DistributionAdds
    render: RenderReport
    reference_renderer: ReferenceLoop | None
    ratio: Ratios
    synthetic: SyntheticRun | None
    runs: int | None = _omitted_when_absent()
    dropped_max: dict[str, dict[str, int]] | None = _omitted_when_absent()
    each_run: list[BenchReport] | None = _omitted_when_absent()

    def to_json(self) -> dict[str, Any]:
        """The JSON written, as plain data."""
        return self.model_dump(mode="json")


def summary_ms(values_s: list[float] | np.ndarray) -> Summary:
    """n, p50, p99, max and mean in milliseconds of durations given in seconds."""
    v = 1000.0 * np.asarray(values_s, dtype=float)
    if v.size == 0:
        return Summary(n=0, p50=None, p99=None, max=None, mean=None)
    p50, p99 = np.percentile(v, [50, 99])
    return Summary(
        n=int(v.size),
        p50=round(float(p50), 4),
        p99=round(float(p99), 4),
        max=round(float(v.max()), 4),
        mean=round(float(v.mean()), 4),
    )


def frames_over_goal(latencies_s: list[float]) -> int:
    """How many of the latencies (s) exceed :data:`LATENCY_GOAL_MS`."""
    return sum(1000.0 * v > LATENCY_GOAL_MS for v in latencies_s)


def median_of_runs(runs: list[BenchReport]) -> BenchReport:
    """One report whose every number is the median of that number over ``runs`` (a count the
    lower median, so that it stays a count; anything else is taken from the first run), with
    ``runs`` (how many), the pooled tail over all their frames, ``dropped_max`` (since one drop
    matters: the largest count per stage over the runs) and ``each_run``."""

    def merge(values: list[Any]) -> Any:
        first = values[0]
        if isinstance(first, bool) or first is None:
            return first
        if isinstance(first, int):
            return statistics.median_low(v for v in values if isinstance(v, int))
        if isinstance(first, float):
            numbers = [v for v in values if isinstance(v, int | float)]
            return round(float(np.median(numbers)), 4)
        if isinstance(first, dict):
            return {k: merge([v.get(k) for v in values if isinstance(v, dict)]) for k in first}
        return first

    out = merge([r.model_dump() for r in runs])
    for part in ("distributed", "inprocess"):  # frame by frame: in each run, not medians
        out[part]["frames_ms"] = None
    rows = [row for r in runs for row in r.distributed.frames_ms or []]
    every_frame_s = [row["latency_ms"] / 1000.0 for row in rows]
    every_handoff_s = [(row["publish"] + row["frame_transport"]) / 1000.0 for row in rows]
    out["distributed"]["pooled"] = Pooled(
        latency_ms=summary_ms(every_frame_s),
        frames_over_goal=frames_over_goal(every_frame_s),
        frame_handoff_ms=summary_ms(every_handoff_s),
    )
    out["runs"] = len(runs)
    parts = {"distributed": [r.distributed.dropped for r in runs]}
    if runs[0].synthetic is not None:
        parts["synthetic"] = [r.synthetic.dropped for r in runs if r.synthetic is not None]
    out["dropped_max"] = {
        part: {k: max(d[k] for d in dropped) for k in dropped[0]} for part, dropped in parts.items()
    }
    out["each_run"] = runs
    return BenchReport.model_validate(out)


def load_json(path: str | Path) -> BenchReport:
    """A report ``umay bench --json`` wrote."""
    return BenchReport.model_validate_json(Path(path).read_text())


def write_json(report: BenchReport, path: str | Path) -> None:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(report.to_json(), indent=2) + "\n")
