"""A law stuck in a local minimum, through the real services (lockstep, loopback, own
prefix): from campaign start 3 the thesis's constant Jacobian would lower the hand onto the
object's top face 35 mm from its goal; with the clearance lifting its twist straight up
(``controller.clearance_correction = "lift"``) it holds the hand there, and the error settles
at 23 px. ``umay run`` ends it as stalled within stall_after_s of its best error, naming the
clearance; under ``umay up`` the controller's status says it is stalled, since when, and that
the clearance holds the hand. With the default correction (the law's least squares under the
clearance) the same start converges. Start 3's goal is one constant's frozen matrix makes
unstable (services/controller/stability.py): its unstable direction is what lowers the hand,
and both ``umay run`` before launch and the controller's status say so."""

from __future__ import annotations

import json
import signal
from pathlib import Path

from common.session import open_session
from deploy.experiments.campaign.starts import start_overrides
from services.controller.progress import HELD_BY_CLEARANCE
from tests.conftest import launch_umay_up, views_once_controller
from tests.integration.test_integration import umay_run

REPO = Path(__file__).resolve().parents[2]
BASE = str(REPO / "deploy/scenarios/suite/01_baseline.toml")


def campaign_start(name: str, *sets: str) -> list[str]:
    """A start of the published campaign as ``umay run`` arguments, constant strategy."""
    starts = json.loads((REPO / "docs/campaign/starts.json").read_text())
    s = next(x for x in starts if x["name"] == name)
    items = start_overrides(s["name"], s["q0_rad"], s["target_position_m"], s["target_yaw_rad"])
    args = ["--scenario", BASE, "--mode", "constant"]
    for item in [*items, "run.timeout_s=40.0", *sets]:
        args += ["--set", item]
    return args


def start_3() -> list[str]:
    """Start 3 with the clearance's twist lifted straight up: the stall against it."""
    return campaign_start("start_0003", "controller.clearance_correction='lift'")


def test_the_laws_least_squares_under_the_clearance_leaves_that_stall(tmp_path: Path) -> None:
    proc, r = umay_run(tmp_path, *campaign_start("start_0003"))
    assert r is not None, proc.stderr
    assert proc.returncode == 0 and r["reason"] == "converged", r


def test_umay_run_ends_a_stalled_law_early_naming_its_best_error(tmp_path: Path) -> None:
    proc, r = umay_run(tmp_path, *start_3())
    assert r is not None, proc.stderr
    assert proc.returncode == 1 and r["reason"] == "stalled", r
    assert "makes this goal unstable" in proc.stderr, proc.stderr  # warned before launch
    # ... and by the controller, from the target it measured, when it froze its matrix
    assert "makes it unstable" in (tmp_path / "logs" / "controller.log").read_text()
    assert r["sim_time_s"] < 10.0, r  # not the 40 s timeout
    assert "not below" in r["detail"] and HELD_BY_CLEARANCE in r["detail"], r
    assert r["final_pixel_rms"] > 5.0, r


def test_umay_up_keeps_going_and_status_says_it_is_stalled(tmp_path: Path) -> None:
    args = [a for a in start_3() if a != "--mode" and a != "constant"]
    args += ["--set", "controller.mode='constant'"]
    proc, keys, endpoint = launch_umay_up(tmp_path / "logs", "lockstep", *args)
    session = open_session(connect=[endpoint])
    try:
        controller = views_once_controller(proc, session, keys, "stalled", 120).get("controller")
        assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
        assert controller is not None and controller.status.fields["stalled"], controller
        fields = controller.status.fields
        assert fields["stalled_for_s"] >= 5.0 and fields["error_best_px"] > 5.0, fields
        reason = controller.status.degraded_reason
        assert reason.startswith("stalled: image error"), fields
        assert reason.endswith(HELD_BY_CLEARANCE), reason
        assert not fields["converged"] and not fields["holding"], fields
        assert fields["goal_stability"] < 0.0, fields  # the frozen matrix leaves this goal
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
        session.close()
