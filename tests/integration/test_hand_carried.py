"""A hand marker its own forearm hides for a moment, through the real services (lockstep,
loopback, own prefix): from campaign start 174 constant's path turns the forearm across the
hand marker. Carried from its last view along the encoders' motion (the default,
``controller.predict_hand_s``) the hand is servoed on through it and the run converges; with
the prediction off the controller holds until the run is reported stuck, waiting for the hand."""

from __future__ import annotations

from pathlib import Path

from tests.integration.test_integration import umay_run
from tests.integration.test_stall_integration import campaign_start


def test_a_hand_hidden_for_a_moment_is_carried_by_the_encoders(tmp_path: Path) -> None:
    proc, r = umay_run(tmp_path / "carried", *campaign_start("start_0174"))
    assert r is not None, proc.stderr
    assert proc.returncode == 0 and r["reason"] == "converged", r
    proc, r = umay_run(
        tmp_path / "held", *campaign_start("start_0174", "controller.predict_hand_s=0")
    )
    assert r is not None, proc.stderr
    assert proc.returncode == 1 and r["reason"] == "stuck", r
    assert "waiting for: hand partial" in r["detail"], r
