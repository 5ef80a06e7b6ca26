"""``umay status`` against running services: every field is there, a killed service shows."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from common.keys import SERVICES
from common.session import free_tcp_endpoint, open_session
from deploy.launch.status import collect
from deploy.supervisor import Supervisor
from tests.conftest import launch_umay_up
from tests.prefixes import unique_keys, unique_prefix


def test_status_lists_all_services_and_sees_a_killed_one_go(tmp_path: Path) -> None:
    endpoint = free_tcp_endpoint()
    keys = unique_keys()
    session = open_session(connect=[], listen=[endpoint])
    sup = Supervisor(None, keys.prefix, endpoint, tmp_path / "logs")
    sup.start()
    try:
        deadline = time.monotonic() + 60
        views = []
        while time.monotonic() < deadline:
            views = collect(session, keys, 0.5)
            running = [v for v in views if v.status and v.alive and v.status.received]
            traffic = all(st.count > 0 for v in running for st in v.status.received.values())
            if len(running) == 4 and traffic:
                break
            time.sleep(0.3)
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "deploy",
                "status",
                "--json",
                "--prefix",
                keys.prefix,
                "--connect",
                endpoint,
            ],
            capture_output=True,
            text=True,
            timeout=30,
        )
        assert proc.returncode == 0, proc.stderr
        out = json.loads(proc.stdout)
        assert set(out) == set(SERVICES)
        for name, entry in out.items():
            assert entry["alive"], name
            st = entry["status"]
            assert st["pid"] > 0 and st["host"] and st["uptime_s"] > 0
            assert st["state"] in {"running", "degraded"}
            for key_stats in list(st["received"].values()) + list(st["published"].values()):
                assert {"count", "rate_hz", "age_s", "dropped"} <= set(key_stats)
            assert st["processing_ms_p50"] is not None and st["processing_ms_p99"] is not None
        sim_fields = out["sim"]["status"]["fields"]
        assert {"sim_time_s", "real_time_factor", "render_ms", "dropped_frames"} <= set(sim_fields)
        # Camera frames by reference (one host), none whole.
        assert sim_fields["frames_by_ref"] > 0 and sim_fields["frames_by_copy"] == 0
        assert sim_fields["frames_copy_reason"] == "" and sim_fields["whole_frames_served"] == 0
        vision_fields = out["vision"]["status"]["fields"]
        assert {"markers", "lost_reasons", "depth_age_s"} <= set(vision_fields)
        assert vision_fields["frames_by_ref"] > 0 and vision_fields["frames_by_copy"] == 0
        assert vision_fields["frames_overwritten"] == 0
        assert {"mode", "error_px_rms", "converged"} <= set(out["controller"]["status"]["fields"])
        assert {"deadman", "saturated_joints"} <= set(out["actuation"]["status"]["fields"])
        # Each log starts with what the service runs on: its prefix, inputs and outputs.
        vision_log = (tmp_path / "logs" / "vision.log").read_text()
        assert f"vision running under {keys.prefix}; in: sim/rgb, sim/depth; out: " in vision_log
        for name in SERVICES:
            assert (
                f"{name} running under {keys.prefix}"
                in (tmp_path / "logs" / f"{name}.log").read_text()
            )

        # --watch with --json: a JSON document a line, every second, until Ctrl-C.
        watch = subprocess.Popen(
            [sys.executable, "-m", "deploy", "status", "--json", "--watch", "--prefix",
             keys.prefix, "--connect", endpoint],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert watch.stdout is not None
        lines = [json.loads(watch.stdout.readline()) for _ in range(2)]
        watch.send_signal(signal.SIGINT)
        assert watch.wait(timeout=30) == 0, watch.stderr.read() if watch.stderr else ""
        assert all(set(line) == set(SERVICES) for line in lines)
        uptimes = [line["sim"]["status"]["uptime_s"] for line in lines]
        assert uptimes[1] >= uptimes[0] + 0.9, uptimes  # refreshed, not printed twice

        pid = sup.children["vision"].process.pid
        os.kill(pid, signal.SIGKILL)
        killed = time.monotonic()
        gone_after = None
        while time.monotonic() - killed < 10:
            vision = next(v for v in collect(session, keys, 0.3) if v.name == "vision")
            if vision.condition == "gone":
                gone_after = time.monotonic() - killed
                break
        print(f"vision shown as gone {gone_after} s after kill -9")
        assert gone_after is not None and gone_after < 2.0
    finally:
        sup.stop()
        session.close()


@pytest.mark.parametrize("shm_mount", ["size=1m", "ro"])
def test_without_room_for_shared_memory_frames_go_whole(tmp_path: Path, shm_mount: str) -> None:
    """A host whose /dev/shm cannot hold the frame ring (1 MiB, as in a small container) or
    cannot be written at all (read-only, where Zenoh cannot even open a session with shared
    memory): the sim says why in its status, and the frames reach vision whole, by copy, so
    the loop still runs. The pipeline runs in a mount namespace of its own with that
    /dev/shm; the test's session, outside it, queries the status over TCP. Needs root (to
    mount), as CI has."""
    if os.geteuid() != 0:
        pytest.fail("this test mounts a small /dev/shm in a mount namespace: run it as root")
    mount_then_exec = f'mount -t tmpfs -o size=1m,{shm_mount} tmpfs /dev/shm && exec "$@"'
    wrapper = ("unshare", "-m", "sh", "-c", mount_then_exec, "sh")
    proc, keys, endpoint = launch_umay_up(tmp_path / "logs", "lockstep", wrapper=wrapper)
    session = open_session(connect=[endpoint])
    try:
        deadline, views = time.monotonic() + 90, {}
        while time.monotonic() < deadline and proc.poll() is None:
            views = {v.name: v for v in collect(session, keys, 0.5)}
            controller = views.get("controller")
            status = controller.status if controller else None
            twists = status.published.get(keys.twist) if status else None
            if twists is not None and twists.count >= 10:
                break
            time.sleep(0.3)
        assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
        assert all(views.get(name) and views[name].alive for name in SERVICES), views
        sim = views["sim"].status.fields
        reason = "no room for a ring" if shm_mount.startswith("size") else "Read-only"
        assert reason in sim["frames_copy_reason"], sim
        rgb = views["vision"].status.received[keys.rgb]
        assert rgb.count >= 10 and rgb.by_ref == 0 and rgb.by_copy == rgb.count
        assert rgb.fetched == 0 and rgb.dropped == 0
        assert sim["frames_by_ref"] == 0
        assert sim["frames_by_copy"] >= 2 * rgb.count  # every rgb and depth frame
        assert views["controller"].status.published[keys.twist].count >= 10
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
        session.close()


def test_status_with_nothing_running_exits_1_saying_where_it_looked() -> None:
    endpoint = free_tcp_endpoint()  # nobody listens there
    prefix = unique_prefix()
    proc = subprocess.run(
        [sys.executable, "-m", "deploy", "status", "--prefix", prefix, "--connect", endpoint,
         "--timeout", "0.3"],
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert proc.returncode == 1, proc.stderr
    assert "no service answers under prefix" in proc.stderr and endpoint in proc.stderr
    assert "gone" in proc.stdout and "Traceback" not in proc.stderr


def test_a_session_that_cannot_open_is_reported_without_a_traceback() -> None:
    # Well formed, so argparse lets it through; Zenoh refuses it when the session opens.
    proc = subprocess.run(
        [sys.executable, "-m", "deploy", "status", "--connect", "nolink/127.0.0.1:1"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 1, proc.stderr
    assert "umay status: Zenoh: Unicast not supported for nolink protocol" in proc.stderr
    assert "Traceback" not in proc.stderr
