"""``umay run`` and ``umay up``: launch the services, watch the run, report."""

from __future__ import annotations

import json
import logging
import socket
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from common.codec import DEFAULT_MAX_BYTES, MessageError, decode
from common.config import Scenario, load_scenario
from common.keys import Keys
from common.messages import EndEffectorTwist, SimTruth
from common.runtime import parse_overrides
from common.transport import DEFAULT_ENDPOINT, free_tcp_endpoint, open_session
from deploy.evaluate import RunResult, summarize
from deploy.reachability import check_scenario
from deploy.supervisor import Supervisor

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

    def on_truth(self, sample) -> None:
        try:
            t = decode(sample.payload.to_bytes(), SimTruth, DEFAULT_MAX_BYTES)
        except MessageError as exc:
            log.warning("bad truth message: %s", exc)
            return
        self.truths[t.header.frame_seq] = t

    def on_twist(self, sample) -> None:
        try:
            tw = decode(sample.payload.to_bytes(), EndEffectorTwist, DEFAULT_MAX_BYTES)
        except MessageError as exc:
            log.warning("bad twist message: %s", exc)
            return
        seq = tw.header.frame_seq
        self.twists[seq] = tw
        if self.decided.is_set():
            return
        if tw.converged:
            self.converged_frame = seq
            self.decided.set()
        elif tw.header.sim_time_s >= self.timeout_s:
            self.timeout_frame = seq
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
) -> RunResult:
    """Launch the four services, servo until converged or timeout, stop them, judge the run."""
    endpoint = listen or default_listen_endpoint()
    keys = Keys(prefix)
    monitor = RunMonitor(timeout_s=scenario.run.timeout_s)
    session = open_session(connect=[], listen=[endpoint])
    subs = [
        session.declare_subscriber(keys.truth, monitor.on_truth),
        session.declare_subscriber(keys.twist, monitor.on_twist),
    ]
    sup = Supervisor(scenario_path, prefix, endpoint, log_dir, overrides)
    started = time.monotonic()
    # Lockstep speed depends on the machine (rendering dominates): allow generously.
    wall_limit = wall_timeout_s or max(120.0, 20.0 * scenario.run.timeout_s)
    reason, detail = "error", ""
    last_print = 0.0
    try:
        sup.start()
        while True:
            if monitor.decided.wait(0.2):
                reason = "converged" if monitor.converged_frame is not None else "timeout"
                break
            dead = sup.exited()
            if dead:
                names = ", ".join(f"{c.name} (exit {c.exit_codes[-1]})" for c in dead)
                detail = f"service exited: {names}; see {log_dir}"
                break
            elapsed = time.monotonic() - started
            if elapsed > wall_limit:
                reason, detail = "timeout", f"wall-clock limit of {wall_limit:.0f} s reached"
                break
            tw = monitor.latest()
            if not quiet and tw is not None and elapsed - last_print > 1.0:
                last_print = elapsed
                print(
                    f"\r frame {tw.header.frame_seq:5d}  sim {tw.header.sim_time_s:6.2f} s  "
                    f"error {tw.error_px_rms:8.3f} px  ({scenario.controller.mode.value})",
                    end="",
                    file=sys.stderr,
                    flush=True,
                )
    finally:
        sup.stop()
        for s in subs:
            s.undeclare()
        session.close()
        if not quiet:
            print(file=sys.stderr)
    wall = time.monotonic() - started
    if reason == "converged":
        last = monitor.converged_frame
    elif reason == "timeout" and monitor.timeout_frame is not None:
        last = monitor.timeout_frame
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
    )


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
