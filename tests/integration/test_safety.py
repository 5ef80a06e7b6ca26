"""Safety chain end to end: the controller dies mid-motion and is not restarted; the joint
speeds must reach zero within 300 ms (actuation deadman, 200 ms): the zero command published,
and applied to the motors (the sim's own stamp, ``SimTiming.applied``), within 300 ms of the
kill, and every encoder sample from the next physics step on still.

(The encoders alone cannot time the stop: they are sampled once per rendered frame, ~200 ms
apart at 640×480, and a sample in flight at the kill moves the estimate by a whole frame.)"""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import numpy as np

from common.codec import DEFAULT_MAX_BYTES, decode
from common.keys import SERVICES
from common.messages import AppliedCommand, JointState, JointVelocityCommand, SimTiming
from common.session import open_session
from deploy.launch.status import collect
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

    applied: list[AppliedCommand] = []
    render_start_s: dict[int, float] = {}  # per frame: its joint state was read just before

    def on_timing(sample) -> None:
        msg = decode(sample.payload.to_bytes(), SimTiming, DEFAULT_MAX_BYTES)
        with lock:
            applied.extend(msg.applied)
            render_start_s[msg.header.frame_seq] = msg.render_start_s

    subs = [
        session.declare_subscriber(keys.joint_command, on_command),
        session.declare_subscriber(keys.joint_state, on_state),
        session.declare_subscriber(keys.timing, on_timing),
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
        killed, killed_wall_s = time.monotonic(), time.time()
        time.sleep(1.5)
        with lock:
            after = [(t, c) for t, c in commands if t > killed]
            states_now, applied_now, starts = (
                [s for _, s in states],
                list(applied),
                dict(render_start_s),
            )
        stop = next(((t, c) for t, c in after if not np.any(c.velocity_rad_s)), None)
        assert stop is not None, "no zero command after the controller died"
        wall_ms = 1000 * (stop[0] - killed)
        # When the motors took the zero command, by the sim's clock (same host, Unix time).
        sent = stop[1].header.send_time_s
        taken = next((a for a in applied_now if a.send_time_s == sent), None)
        assert taken is not None, "the sim never applied the zero command"
        applied_ms = 1000 * (taken.applied_time_s - killed_wall_s)
        # A frame's joint state is read and sent before its render: the samples read
        # after the stop are those of frames whose render started after it (one sim thread).
        # The first of them may be read before the next physics step, i.e. still show the
        # motion the motors had when they took the command; from the next one on, all still.
        after_stop = sorted(
            (s for s in states_now if starts.get(s.header.frame_seq, 0.0) > taken.applied_time_s),
            key=lambda s: s.header.sim_time_s,
        )
        later = [s for s in after_stop if s.header.sim_time_s > after_stop[0].header.sim_time_s]
        print(
            f"zero command {wall_ms:.0f} ms (wall) after kill -9 ({stop[1].reason}), applied "
            f"to the motors {applied_ms:.0f} ms after; {len(later)} encoder samples since"
        )
        assert stop[1].reason == "deadman"
        # Stamped with the time of the run it stops (a view or recording plots it there).
        assert stop[1].header.sim_time_s > 0.0 and stop[1].header.frame_seq == -1
        # The stop is counted where a user looks for it.
        actuation = {v.name: v for v in collect(session, keys, 1.0)}["actuation"].status
        assert actuation.fields["deadman_stops"] >= 1
        assert {"acceleration_clamps", "velocity_clamps", "position_limit_clamps",
                "nonfinite_guards", "hold_stops"} <= set(actuation.fields)  # fmt: skip
        assert wall_ms <= 300
        assert applied_ms <= 300
        assert later, "no encoder sample after the stop"
        assert all(np.abs(s.velocity_rad_s).max() < 1e-3 for s in later), "joints still moving"
    finally:
        for s in subs:
            s.undeclare()
        proc.send_signal(signal.SIGINT)
        proc.wait(10)
        session.close()
