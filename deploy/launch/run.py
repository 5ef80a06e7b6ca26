"""``umay run`` and ``umay up``: launch the services, watch the run, report."""

from __future__ import annotations

import json
import logging
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import numpy as np
from pydantic import BaseModel
from rich.live import Live
from rich.table import Table
from rich.text import Text

from common import kinematics as kin
from common.codec import DEFAULT_MAX_BYTES, MessageError, decode
from common.config import Scenario, load_scenario
from common.keys import Keys
from common.messages import EndEffectorTwist, SimTruth
from common.runtime import parse_overrides
from common.session import DEFAULT_ENDPOINT, free_tcp_endpoint, open_session
from deploy.consoles import progress_console
from deploy.launch.evaluate import RunResult, pose
from deploy.launch.goal_stability import unstable_goal_warning
from deploy.launch.reachability import check_scenario
from deploy.launch.run_end import EndLimits, HoldState, RunEnd, judge_twist, run_result
from deploy.supervisor import Supervisor
from services.controller.ibvs import ACQUIRING

M = TypeVar("M", bound=BaseModel)
log = logging.getLogger("umay.run")


def default_listen_endpoint(preferred: str = DEFAULT_ENDPOINT) -> str:
    """The well-known endpoint if free (so ``umay status`` finds the system), else any port.

    Free as Zenoh's listener binds it, with ``SO_REUSEADDR``: the connections of the last run
    linger in TIME_WAIT on that port for a minute after it ends, which only a bind without the
    option refuses, and a run right after another must still listen where status looks."""
    host, port = preferred.removeprefix("tcp/").rsplit(":", 1)
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, int(port)))
        except OSError:
            endpoint = free_tcp_endpoint()
            log.warning("%s is busy; listening on %s instead", preferred, endpoint)
            return endpoint
    return preferred


def prepare(scenario_path: str | None, overrides: list[str]) -> Scenario:
    """Validate everything before anything starts (raises ScenarioError)."""
    scenario = load_scenario(scenario_path, parse_overrides(overrides))
    check_scenario(scenario)
    if warning := unstable_goal_warning(scenario):
        log.warning("%s", warning)
    return scenario


@dataclass
class RunMonitor:
    """Collects ground truth and twists per frame (Zenoh callback threads write, run reads) and
    decides the end of the run twist by twist (:func:`deploy.launch.run_end.judge_twist`)."""

    truths: dict[int, SimTruth] = field(default_factory=dict)
    twists: dict[int, EndEffectorTwist] = field(default_factory=dict)
    decided: threading.Event = field(default_factory=threading.Event)
    limits: EndLimits = field(default_factory=EndLimits)  # the scenario's end conditions
    rejected: int = 0
    hold: HoldState = field(default_factory=HoldState)
    end: RunEnd | None = None  # why the run ended, and at which frame

    @property
    def ended(self) -> str:
        """Why the run ended before converging or timing out (stuck, ...), else ""."""
        if self.end is None or self.end.reason in ("converged", "timeout"):
            return ""
        return self.end.reason

    @property
    def ended_detail(self) -> str:
        return self.end.detail if self.ended else ""

    @property
    def ended_frame(self) -> int | None:
        return self.end.frame if self.ended and self.end is not None else None

    def _decode(self, sample, model: type[M]) -> M | None:
        try:
            return decode(sample.payload.to_bytes(), model, DEFAULT_MAX_BYTES)
        except MessageError as exc:
            self.rejected += 1
            if self.rejected in (1, 10, 100, 1000) or self.rejected % 10_000 == 0:
                log.warning("run monitor rejected %d message(s); last: %s", self.rejected, exc)
            return None

    def on_truth(self, sample) -> None:
        t = self._decode(sample, SimTruth)
        if t is not None:
            self.truths[t.header.frame_seq] = t

    def on_twist(self, sample) -> None:
        tw = self._decode(sample, EndEffectorTwist)
        if tw is None:
            return
        self.twists[tw.header.frame_seq] = tw
        if self.decided.is_set():
            return
        self.hold, end = judge_twist(self.limits, self.hold, tw)
        if end is not None:
            self.end = end
            self.decided.set()

    def latest(self) -> EndEffectorTwist | None:
        return self.twists[max(self.twists)] if self.twists else None


def run_once(
    scenario_path: str | None,
    scenario: Scenario,
    overrides: list[str],
    prefix: str,
    log_dir: Path,
    listen: str | None = None,
    wall_timeout_s: float | None = None,
    quiet: bool = False,
    record: Path | None = None,
    stop: threading.Event | None = None,
    record_frames: bool = True,
) -> RunResult:
    """Launch the four services, servo until converged or timeout, stop them, judge the run.

    ``record``: write every data message of the run to this MCAP file (see deploy.recording.record),
    the camera frames left out unless ``record_frames``.
    ``stop``: set from another thread to end the run early (reason "error", detail
    "interrupted"); the services are stopped as after any run.
    """
    endpoint = listen or default_listen_endpoint()
    keys = Keys(prefix)
    limits = EndLimits.of(scenario)
    monitor = RunMonitor(limits=limits)
    session = open_session(connect=[], listen=[endpoint])
    recorder = None
    if record is not None:
        from deploy.recording.record import Recorder, run_metadata

        metadata = run_metadata(scenario_path, overrides, prefix)
        recorder = Recorder(
            record, session, keys, metadata=metadata, without_frames=not record_frames
        )
    subs = [
        session.declare_subscriber(keys.truth, monitor.on_truth),
        session.declare_subscriber(keys.twist, monitor.on_twist),
    ]
    sup = Supervisor(
        scenario_path, prefix, endpoint, log_dir, overrides, config=scenario.supervisor,
        session=session,
    )  # fmt: skip
    started = time.monotonic()
    # Lockstep speed depends on the machine (rendering dominates): allow generously.
    wall_limit = wall_timeout_s or max(120.0, 20.0 * scenario.run.timeout_s)
    reason, detail = "error", ""
    last_print = 0.0
    live = None if quiet else Live(Text("starting the services..."), console=progress_console())
    try:
        if live is not None:
            live.start()
        sup.start()
        while True:
            if monitor.decided.wait(0.2):
                assert monitor.end is not None
                reason, detail = monitor.end.reason, monitor.end.detail
                break
            if stop is not None and stop.is_set():
                detail = "interrupted"
                break
            for event in sup.check_hangs():  # a run does not restart: a hang ends it
                log.warning("%s", event)
            dead = sup.exited()
            if dead:
                names = ", ".join(c.describe_exit() for c in dead)
                detail = f"service exited: {names}; see {log_dir}"
                break
            elapsed = time.monotonic() - started
            if elapsed > wall_limit:
                reason, detail = "timeout", f"wall-clock limit of {wall_limit:.0f} s reached"
                break
            if live is not None and elapsed - last_print > 0.5:
                last_print = elapsed
                live.update(progress_line(monitor, scenario, elapsed))
    finally:
        sup.stop()
        if recorder is not None:
            recorder.close()
        for s in subs:
            s.undeclare()
        session.close()
        if live is not None:  # the last frame's line, not the one of half a second before
            live.update(progress_line(monitor, scenario, time.monotonic() - started))
            live.stop()
            if not live.console.is_terminal:  # a log or a pipe: its last line ends here
                live.console.line()
    wall = time.monotonic() - started
    return run_result(scenario, reason, detail, monitor.end, monitor.truths, monitor.twists, wall)


def progress_line(monitor: RunMonitor, scenario: Scenario, elapsed_s: float) -> Text:
    """frame, mode, feature error, distance to the goal (from ground truth, for the operator
    only), and the loop rate."""
    tw = monitor.latest()
    if tw is None:
        return Text(f"waiting for the first frame... {elapsed_s:.0f} s")
    seq = tw.header.frame_seq
    truth = monitor.truths.get(seq)
    distance = "-"
    if truth is not None:
        goal = kin.goal_marker_pose(
            pose(truth.target_marker_pose), scenario.target.approach_height_m
        )
        gap = np.linalg.norm(pose(truth.hand_marker_pose)[:3, 3] - goal[:3, 3])
        distance = f"{1000 * gap:6.1f} mm"
    state = twist_phase(tw)
    return Text(
        f"frame {seq:5d}  {tw.mode:8s}  error {tw.error_px_rms:8.3f} px  "
        f"to goal {distance}  {(seq + 1) / max(elapsed_s, 1e-9):5.1f} frames/s  {state}"
    )


def twist_phase(tw: EndEffectorTwist) -> str:
    """``converged``, ``servoing``, ``acquiring: ...`` or ``holding: why``; a moving twist the
    clearance lifted says so (``servoing, lifted above the object``)."""
    if tw.converged:
        return "converged"
    if not tw.valid:
        return f"holding: {tw.hold_reason}"
    phase = tw.hold_reason if tw.hold_reason.startswith(ACQUIRING) else "servoing"
    return f"{phase}, lifted above the object" if tw.lifted else phase


def result_table(result: RunResult) -> Table:
    def num(v: float | None, fmt: str, scale: float = 1.0) -> str:
        return "n/a" if v is None else format(v * scale, fmt)

    t = Table(title=f"{result.scenario} · {result.mode} · {result.clock}", show_header=False)
    t.add_column("what")
    t.add_column("value", justify="right")
    colour = "green" if result.converged else "red"
    t.add_row(
        "result", f"[{colour}]{result.reason}[/]" + (f" ({result.detail})" if result.detail else "")
    )
    t.add_row("frames", str(result.frames))
    t.add_row("simulated time", f"{result.sim_time_s:.2f} s")
    t.add_row("wall time", f"{result.wall_time_s:.1f} s")
    t.add_row("pixel RMS", f"{num(result.final_pixel_rms, '.3f')} px")
    t.add_row("position error", f"{num(result.final_position_error_m, '.2f', 1000.0)} mm")
    t.add_row("orientation error", f"{num(result.final_orientation_error_deg, '.2f')} deg")
    t.add_row("hand path length", f"{num(result.path_length_m, '.3f')} m")
    return t


def format_result(result: RunResult) -> str:
    def num(v: float | None, fmt: str, scale: float = 1.0) -> str:
        return "n/a" if v is None else format(v * scale, fmt)

    return "\n".join(
        [
            f"scenario {result.scenario}  mode {result.mode}  clock {result.clock}",
            f"  result            {result.reason}"
            + (f" ({result.detail})" if result.detail else ""),
            f"  frames            {result.frames}  ({result.sim_time_s:.2f} s simulated, "
            f"{result.wall_time_s:.1f} s wall)",
            f"  pixel RMS         {num(result.final_pixel_rms, '.3f')} px",
            f"  position error    {num(result.final_position_error_m, '.2f', 1000.0)} mm",
            f"  orientation error {num(result.final_orientation_error_deg, '.2f')} deg",
            f"  hand path length  {num(result.path_length_m, '.3f')} m",
        ]
    )


def write_result(result: RunResult, path: str | Path) -> None:
    Path(path).write_text(json.dumps(result.model_dump(), indent=2) + "\n")
