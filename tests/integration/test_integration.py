"""Multi-process tests: the real services as separate OS processes over Zenoh on loopback.

Each test uses its own key prefix and its own listening port, and multicast scouting is off,
so parallel runs never cross.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from common.codec import encode
from common.config import load_scenario
from common.keys import Keys
from common.messages import EndEffectorTwist, Features, Header, JointState, MarkerFeatures
from common.session import ENV_SHM, free_tcp_endpoint, open_session
from deploy.launch.evaluate import RunResult
from deploy.launch.run_inprocess import run_scenario_inprocess
from deploy.queries import query_status
from tests.conftest import launch_umay_up, views_once_controller
from tests.prefixes import unique_prefix

UMAY = [sys.executable, "-m", "deploy"]
RUN_TIMEOUT_S = 900


def umay_run(
    tmp_path: Path, *args: str, env: dict[str, str] | None = None
) -> tuple[subprocess.CompletedProcess, dict | None]:
    """``umay run`` under a unique prefix; ``env``: extra environment variables."""
    result = tmp_path / f"result-{uuid.uuid4().hex[:6]}.json"
    proc = subprocess.run(
        [
            *UMAY,
            "run",
            "--quiet",
            "--prefix",
            unique_prefix(),
            "--listen",
            free_tcp_endpoint(),
            "--log-dir",
            str(tmp_path / "logs"),
            "--result",
            str(result),
            *args,
        ],
        capture_output=True,
        text=True,
        timeout=RUN_TIMEOUT_S,
        env=None if env is None else {**os.environ, **env},
    )
    data = json.loads(result.read_text()) if result.exists() else None
    return proc, data


@pytest.mark.parametrize("mode", ["constant", "dynamic", "pmj", "mpj", "points3d"])
def test_each_strategy_converges_from_the_default_scenario(mode: str) -> None:
    """In one process (the same loop to the bit: the test below and
    test_pipeline_vs_distributed.py); every strategy through the four service processes:
    test_compare_run.py's figure runs."""
    r = run_scenario_inprocess(load_scenario(None, {"controller": {"mode": mode}}))
    assert r.converged and r.reason == "converged", r
    assert r.final_pixel_rms is not None and r.final_pixel_rms < 1.0, r
    assert r.final_position_error_m is not None and r.final_position_error_m < 0.005, r
    assert r.mode == mode and r.frames > 10 and r.path_length_m > 0.02


def test_neither_wall_clock_nor_the_transport_nor_the_process_split_changes_a_lockstep_run(
    tmp_path: Path,
) -> None:
    """The default run through the four services converges. Wall-clock timing must not leak
    into it: in the second run the actuation deadman fires between every pair of frames (5 ms
    timeout), as it would on a loaded machine where rendering takes longer than the 200 ms
    default. Nor may the way frames travel: the second run has frames by reference off
    (``UMAY_ZENOH_SHM=0``), so they go whole. Nor the processes: the in-process pipeline gives
    the same. The three runs are the same, frame for frame."""
    _, first = umay_run(tmp_path, "--mode", "dynamic")
    assert first is not None and first["reason"] == "converged", first
    assert first["final_position_error_m"] < 0.005, first
    deadman = ("--set", "actuation.deadman_timeout_s=0.005")
    _, second = umay_run(tmp_path, "--mode", "dynamic", *deadman, env={ENV_SHM: "0"})
    assert second is not None
    inprocess = run_scenario_inprocess(load_scenario(None, {}))
    wall = {"wall_time_s"}
    a, b = (RunResult.model_validate(r).model_dump(exclude=wall) for r in (first, second))
    assert a == b
    assert a == inprocess.model_dump(exclude=wall)  # the float fields to the last bit


def test_camera_frames_go_by_reference_and_the_loop_converges(tmp_path: Path) -> None:
    """One host: the sim draws every colour frame and depth image straight into its
    shared-memory ring and sends them by reference, vision reads them all in place, none is
    overwritten while read, and the lockstep loop converges."""
    proc, keys, endpoint = launch_umay_up(tmp_path / "logs", "lockstep")
    session = open_session(connect=[endpoint])
    try:
        views = views_once_controller(proc, session, keys, "converged", RUN_TIMEOUT_S)
        assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
        assert views["controller"].status.fields["converged"], views
        sim, vision = views["sim"].status, views["vision"].status
        sent = sim.published[keys.rgb].count + sim.published[keys.depth].count
        assert sim.fields["frames_by_ref"] == sent > 0 and sim.fields["frames_by_copy"] == 0
        assert sim.fields["frames_copy_reason"] == "" and sim.fields["whole_frames_served"] == 0
        # Drawn by OpenGL straight into the ring's slots: not one frame copied into the ring.
        assert sim.fields["renderer"] == "gl", sim.fields["renderer_detail"]
        assert sim.fields["frames_copied_to_ring"] == 0
        assert 0 < sim.fields["frames_in_place"] <= sim.fields["frames_by_ref"]
        for key in (keys.rgb, keys.depth):
            stats = vision.received[key]
            assert stats.by_ref == stats.count > 0 and stats.by_copy == stats.fetched == 0, key
        assert vision.fields["frames_overwritten"] == 0 and vision.rejected == 0
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
        session.close()


def test_bad_input_exits_2_from_the_umay_process(tmp_path: Path) -> None:
    """A bad field refused through ``python -m deploy``, as a shell sees it: exit 2, naming
    it, nothing launched (every command's bad input, in-process: ``unit/test_cli.py``)."""
    proc, data = umay_run(tmp_path, "--set", "controller.gain=-1")
    assert proc.returncode == 2 and "controller.gain" in proc.stderr, proc.stderr
    assert data is None and not (tmp_path / "logs").exists()


def marker(u0: float) -> MarkerFeatures:
    corners = [[u0, 200.0], [u0 + 50, 200.0], [u0 + 50, 250.0], [u0, 250.0]]
    return MarkerFeatures(
        state="visible",
        corners_px=corners,
        depth_m=[0.5] * 4,
        depth_sigma_m=[0.001] * 4,
        points_m=[[(u - 319.5) * 0.5 / 589.0, (v - 239.5) * 0.5 / 589.0, 0.5] for u, v in corners],
    )


def test_a_service_survives_malformed_payloads_and_counts_them(tmp_path: Path) -> None:
    endpoint = free_tcp_endpoint()
    keys = Keys(unique_prefix())
    session = open_session(connect=[], listen=[endpoint])
    twists: list[EndEffectorTwist] = []
    from common.codec import DEFAULT_MAX_BYTES, decode

    sub = session.declare_subscriber(
        keys.twist,
        lambda s: twists.append(decode(s.payload.to_bytes(), EndEffectorTwist, DEFAULT_MAX_BYTES)),
    )
    env = dict(os.environ, UMAY_ZENOH_CONNECT=endpoint)
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.controller", "--prefix", keys.prefix],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    try:
        deadline = time.monotonic() + 20
        while not query_status(session, keys, 0.5) and time.monotonic() < deadline:
            time.sleep(0.1)
        header = Header(seq=0, sim_time_s=0.0, send_time_s=0.0, frame_seq=0)
        good_features = Features(
            header=header,
            intrinsics={
                "width_px": 640,
                "height_px": 480,
                "fx_px": 589.0,
                "fy_px": 589.0,
                "cx_px": 319.5,
                "cy_px": 239.5,
            },
            hand=marker(300.0),
            target=marker(340.0),
        )
        bad = [
            b"",
            b"\xff\xfe\xfd",
            encode(good_features)[:40],
            encode(header),
            encode(good_features).replace(b"visible", b"visibel"),
        ]
        nan_joints = JointState(header=header, position_rad=[0.1] * 6, velocity_rad_s=[0.0] * 6)
        nan_payload = encode(nan_joints).replace(
            np.float64(0.1).tobytes()[::-1], np.float64("nan").tobytes()[::-1]
        )
        # Put only once the controller's subscriptions reach this session: its status answers
        # from before they are declared, and a payload put earlier is lost, not rejected.
        features_pub = session.declare_publisher(keys.features)
        joints_pub = session.declare_publisher(keys.joint_state)
        while not (features_pub.matching_status.matching and joints_pub.matching_status.matching):
            assert time.monotonic() < deadline, "the controller did not subscribe"
            time.sleep(0.02)
        for payload in bad:
            features_pub.put(payload)
        joints_pub.put(nan_payload)
        time.sleep(0.5)
        assert proc.poll() is None, "the controller died"
        status = query_status(session, keys, 1.0)[0]
        assert status.rejected == len(bad) + 1, status
        assert status.last_rejection
        # Still working: a valid pair of messages gives a twist.
        q = [-1.5, 0.9, -2.0, 1.6, 0.8, -0.3]
        session.put(
            keys.joint_state,
            encode(JointState(header=header, position_rad=q, velocity_rad_s=[0.0] * 6)),
        )
        session.put(keys.features, encode(good_features))
        deadline = time.monotonic() + 5
        while not twists and time.monotonic() < deadline:
            time.sleep(0.05)
        assert twists and twists[0].valid and twists[0].error_px_rms > 10.0
        assert np.linalg.norm(twists[0].linear_m_s) > 0.0
    finally:
        proc.terminate()
        proc.wait(10)
        sub.undeclare()
        session.close()
