"""Turn a run's ground truth and controller outputs into the result record. Pure functions.

Ground truth is used here, and only here, to *judge* a run; nothing flows back to the loop.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel

from common import kinematics as kin
from common.messages import EndEffectorTwist, SimTruth


class RunResult(BaseModel):
    scenario: str
    mode: str
    clock: str
    converged: bool
    reason: str  # converged / timeout / error
    frames: int
    sim_time_s: float
    wall_time_s: float
    final_pixel_rms: float | None
    final_position_error_m: float | None
    final_orientation_error_deg: float | None
    path_length_m: float | None
    detail: str = ""


def pose(values: list[float]) -> np.ndarray:
    return np.array(values).reshape(4, 4)


def square_orientation_error_deg(hand_pose: np.ndarray, target_pose: np.ndarray) -> float:
    """Rotation between the two marker frames, up to the square's 90° symmetry about its normal
    (the four corners look alike, so these four poses are indistinguishable to the camera)."""
    best = np.pi
    for k in range(4):
        turned = target_pose[:3, :3] @ kin.rot_z(k * np.pi / 2)
        best = min(best, kin.rotation_error_rad(hand_pose[:3, :3], turned))
    return float(np.degrees(best))


def path_length_m(truths: dict[int, SimTruth], last_frame: int) -> float:
    points = [truths[k].ee_position_m for k in sorted(truths) if k <= last_frame]
    if len(points) < 2:
        return 0.0
    return float(np.sum(np.linalg.norm(np.diff(np.array(points), axis=0), axis=1)))


def summarize(
    scenario: str,
    mode: str,
    clock: str,
    reason: str,
    last_frame: int | None,
    truths: dict[int, SimTruth],
    twists: dict[int, EndEffectorTwist],
    wall_time_s: float,
    approach_height_m: float,
    detail: str = "",
) -> RunResult:
    """Result at ``last_frame`` (the frame whose twist decided the outcome). Errors compare the
    green marker with its goal: the red marker raised by ``approach_height_m``."""
    truth = truths.get(last_frame) if last_frame is not None else None
    twist = twists.get(last_frame) if last_frame is not None else None
    hand = pose(truth.hand_marker_pose) if truth else None
    target = (
        kin.goal_marker_pose(pose(truth.target_marker_pose), approach_height_m) if truth else None
    )
    return RunResult(
        scenario=scenario,
        mode=mode,
        clock=clock,
        converged=reason == "converged",
        reason=reason,
        frames=0 if last_frame is None else last_frame + 1,
        sim_time_s=truth.header.sim_time_s if truth else 0.0,
        wall_time_s=wall_time_s,
        final_pixel_rms=twist.error_px_rms if twist and twist.valid else None,
        final_position_error_m=(
            float(np.linalg.norm(hand[:3, 3] - target[:3, 3])) if truth else None
        ),
        final_orientation_error_deg=square_orientation_error_deg(hand, target) if truth else None,
        path_length_m=path_length_m(truths, last_frame) if truth else None,
        detail=detail,
    )
