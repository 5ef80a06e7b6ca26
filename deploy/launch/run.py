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
from rich.console import Console
from rich.live import Live
from rich.table import Table
from rich.text import Text

from common import kinematics as kin
from common.codec import DEFAULT_MAX_BYTES, MessageError, decode
from common.config import EventAction, Scenario, load_scenario
from common.keys import Keys
from common.messages import EndEffectorTwist, SimTruth
from common.runtime import parse_overrides
from common.transport import DEFAULT_ENDPOINT, free_tcp_endpoint, open_session
from deploy.experiments.evaluate import RunResult, pose, summarize
from deploy.experiments.reachability import check_scenario
from deploy.launch.supervisor import Supervisor
from services.controller.ibvs import ACQUIRING, ACQUISITION_FAILED

M = TypeVar("M", bound=BaseModel)
log = logging.getLogger("umay.run")


def default_listen_endpoint() -> str:
    """The well-known endpoint if free (so ``umay status`` finds the system), else any port."""
    host, port = DEFAULT_ENDPOINT.removeprefix("tcp/").rsplit(":", 1)
    with socket.socket() as s:
        try:
            s.bind((host, int(port)))
        except OSError:
            endpoint = free_tcp_endpoint()
            log.warning("%s is busy; listening on %s instead", DEFAULT_ENDPOINT, endpoint)
            return endpoint
    return DEFAULT_ENDPOINT


def prepare(scenario_path: str | None, overrides: list[str]) -> Scenario:
    """Validate everything before anything starts (raises ScenarioError)."""
    scenario = load_scenario(scenario_path, parse_overrides(overrides))
    check_scenario(scenario)
    return scenario


@dataclass
class RunMonitor:
    """Collects ground truth and twists per frame (Zenoh callback threads write, run reads)."""

    truths: dict[int, SimTruth] = field(default_factory=dict)
    twists: dict[int, EndEffectorTwist] = field(default_factory=dict)
    decided: threading.Event = field(default_factory=threading.Event)
    converged_frame: int | None = None
    timeout_frame: int | None = None
    timeout_s: float = 30.0
    not_before_s: float = 0.0  # convergence counts once the scenario's events are over
    stuck_after_s: float = 4.0  # a hold this long (sim s) ends the run: stuck
    rejected: int = 0
    hold_since_s: float | None = None  # sim time the current run of holding twists began
    hold_reason: str = ""  # of the latest holding twist
    ended: str = ""  # why the run ended before converging or timing out: stuck, ...
    ended_detail: str = ""
    ended_frame: int | None = None

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
        seq = tw.header.frame_seq
        self.twists[seq] = tw
        if self.decided.is_set():
            return
        t = tw.header.sim_time_s
        if tw.valid:
            self.hold_since_s = None
        else:
            self.hold_since_s = t if self.hold_since_s is None else self.hold_since_s
            self.hold_reason = tw.hold_reason
        if tw.converged and t >= self.not_before_s:
            self.converged_frame = seq
            self.decided.set()
        elif tw.header.sim_time_s >= self.timeout_s:
            self.timeout_frame = seq
            self.decided.set()
        elif not tw.valid and tw.hold_reason.startswith(ACQUISITION_FAILED):
            self.end("acquisition_failed", f"{tw.hold_reason} (held at {t:.2f} s)", seq)
        elif self.hold_since_s is not None and t - self.hold_since_s >= self.stuck_after_s:
            self.end("stuck", stuck_detail(self.hold_reason, self.hold_since_s, t), seq)

    def end(self, reason: str, detail: str, frame: int) -> None:
        self.ended, self.ended_detail, self.ended_frame = reason, detail, frame
        self.decided.set()

    def latest(self) -> EndEffectorTwist | None:
        return self.twists[max(self.twists)] if self.twists else None


def stuck_detail(hold_reason: str, since_s: float, now_s: float) -> str:
    """What a stuck run waited for and since when (sim time)."""
    return (
        f"held {now_s - since_s:.2f} s waiting for: {hold_reason or 'usable features'} "
        f"(holding since sim time {since_s:.2f} s)"
    )


def timeout_detail(monitor: RunMonitor, timeout_s: float) -> str:
    """Why a run that timed out had not converged, from the controller's last output."""
    tw = monitor.latest()
    if tw is None:
        return f"no controller output within {timeout_s:g} s simulated"
    if not tw.valid:
        return f"{timeout_s:g} s simulated; last holding: {tw.hold_reason}"
    phase = tw.hold_reason or "servoing"
    return (
        f"{timeout_s:g} s simulated; still {phase}, image error {tw.error_px_rms:.3f} px "
        "above the convergence threshold"
    )


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
) -> RunResult:
    """Launch the four services, servo until converged or timeout, stop them, judge the run.

    ``record``: write every data message of the run to this MCAP file (see deploy.recording.record).
    ``stop``: set from another thread to end the run early (reason "error", detail
    "interrupted"); the services are stopped as after any run.
    """
    endpoint = listen or default_listen_endpoint()
    keys = Keys(prefix)
    monitor = RunMonitor(
        timeout_s=scenario.run.timeout_s,
        not_before_s=scenario.events_end_s,
        stuck_after_s=scenario.controller.stuck_after_s,
    )
    session = open_session(connect=[], listen=[endpoint])
    recorder = None
    if record is not None:
        from deploy.recording.record import Recorder, run_metadata

        metadata = run_metadata(scenario_path, overrides, prefix)
        recorder = Recorder(record, session, keys, metadata=metadata)
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
    live = None if quiet else Live(Text("starting the services..."), console=Console(stderr=True))
    try:
        if live is not None:
            live.start()
        sup.start()
        while True:
            if monitor.decided.wait(0.2):
                if monitor.converged_frame is not None:
                    reason = "converged"
                elif monitor.ended:
                    reason, detail = monitor.ended, monitor.ended_detail
                else:
                    reason, detail = "timeout", timeout_detail(monitor, scenario.run.timeout_s)
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
        if live is not None:
            live.stop()
    wall = time.monotonic() - started
    if reason == "converged":
        last = monitor.converged_frame
    elif reason == "timeout" and monitor.timeout_frame is not None:
        last = monitor.timeout_frame
    elif monitor.ended and reason == monitor.ended:
        last = monitor.ended_frame
    else:
        last = max(monitor.twists) if monitor.twists else None
    if last is not None and last not in monitor.truths:
        last = max((k for k in monitor.truths if k <= last), default=None)
    return summarize(
        scenario.name,
        scenario.controller.mode.value,
        scenario.run.clock.value,
        reason,
        last,
        monitor.truths,
        monitor.twists,
        wall,
        scenario.target.approach_height_m,
        detail,
        period_s=1.0 / scenario.camera.rgb_hz,
        moving=[(e.at_s, e.end_s) for e in scenario.events if e.action is EventAction.MOVE_TARGET],
        image_size_px=(scenario.camera.width_px, scenario.camera.height_px),
    )


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
    """``converged``, ``servoing``, ``acquiring: ...`` or ``holding: why``."""
    if tw.converged:
        return "converged"
    if not tw.valid:
        return f"holding: {tw.hold_reason}"
    return tw.hold_reason if tw.hold_reason.startswith(ACQUIRING) else "servoing"


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
