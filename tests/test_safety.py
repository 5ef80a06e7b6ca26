"""Safety chain end to end: the controller dies mid-motion and is not restarted; the commanded
joint speeds must reach zero within 300 ms (actuation deadman, 250 ms), in wall and sim time."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import numpy as np

from common.codec import DEFAULT_MAX_BYTES, decode
from common.keys import SERVICES
from common.messages import JointState, JointVelocityCommand
from common.transport import open_session
from deploy.status import collect
from tests.conftest import launch_umay_up


def test_controller_killed_and_not_restarted_motors_stop_within_300_ms(tmp_path: Path) -> None:
    proc, keys, endpoint = launch_umay_up(
        tmp_path / "logs",
        "realtime",
        "--set",
        'supervisor.restart={controller="never"}',
        # Slow servoing, so the arm is still moving when the controller dies.
        "--set",
        "controller.gain=0.3",
    )
    session = open_session(connect=[endpoint])
    commands: list[tuple[float, JointVelocityCommand]] = []
    states: list[tuple[float, JointState]] = []
    lock = threading.Lock()

    def on_command(sample) -> None:
        msg = decode(sample.payload.to_bytes(), JointVelocityCommand, DEFAULT_MAX_BYTES)
        with lock:
            commands.append((time.monotonic(), msg))

    def on_state(sample) -> None:
        msg = decode(sample.payload.to_bytes(), JointState, DEFAULT_MAX_BYTES)
        with lock:
            states.append((time.monotonic(), msg))

    subs = [
        session.declare_subscriber(keys.joint_command, on_command),
        session.declare_subscriber(keys.joint_state, on_state),
    ]
    try:
        deadline = time.monotonic() + 60
        controller_pid = None
        while time.monotonic() < deadline:
            views = {v.name: v for v in collect(session, keys, 0.3)}
            moving = any(np.any(np.abs(c.velocity_rad_s) > 1e-3) for _, c in commands[-3:])
            if all(views.get(n) and views[n].status for n in SERVICES) and moving:
                controller_pid = views["controller"].status.pid
                break
            time.sleep(0.1)
        assert controller_pid, "the arm never started moving"
        os.kill(controller_pid, signal.SIGKILL)
        killed = time.monotonic()
        time.sleep(1.5)
        with lock:
            after = [(t, c) for t, c in commands if t > killed]
            sim_at_kill = [s.header.sim_time_s for t, s in states if t <= killed][-1]
            later_states = [(t, s) for t, s in states if t > killed]
        stop = next((t, c) for t, c in after if not np.any(c.velocity_rad_s))
        wall_ms = 1000 * (stop[0] - killed)
        # When the joints stopped, from the encoders: they are sampled once per rendered frame
        # (slow on a loaded machine), so the stop lies between the last sample that still
        # moved and the first that did not.
        samples = [s for _, s in later_states if s.header.sim_time_s >= sim_at_kill]
        first_still = next(
            i for i, s in enumerate(samples) if np.abs(s.velocity_rad_s).max() < 1e-3
        )
        last_moving_s = (
            samples[first_still - 1].header.sim_time_s if first_still > 0 else sim_at_kill
        )
        sim_ms = 1000 * (last_moving_s - sim_at_kill)
        still_ms = 1000 * (samples[first_still].header.sim_time_s - sim_at_kill)
        print(
            f"zero command {wall_ms:.0f} ms (wall) after kill -9 ({stop[1].reason}); joints "
            f"last seen moving {sim_ms:.0f} ms, first seen still {still_ms:.0f} ms (sim) after"
        )
        assert stop[1].reason == "deadman"
        # The stop is counted where a user looks for it.
        actuation = {v.name: v for v in collect(session, keys, 1.0)}["actuation"].status
        assert actuation.fields["deadman_stops"] >= 1
        assert {"acceleration_clamps", "velocity_clamps", "position_limit_clamps",
                "nonfinite_guards", "hold_stops"} <= set(actuation.fields)  # fmt: skip
        assert wall_ms <= 300
        assert sim_ms <= 300
    finally:
        for s in subs:
            s.undeclare()
        proc.send_signal(signal.SIGINT)
        proc.wait(10)
        session.close()
