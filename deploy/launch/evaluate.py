"""Turn a run's ground truth and controller outputs into the result record. Pure functions.

Ground truth is used here, and only here, to *judge* a run; nothing flows back to the loop.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel

from common import kinematics as kin
from common.messages import EndEffectorTwist, SimTruth


class RunResult(BaseModel):
    """One run, judged against the simulator's ground truth (units in the names)."""

    scenario: str
    mode: str
    clock: str
    converged: bool
    # converged / timeout / stuck / acquisition_failed / error (detail says which and why)
    reason: str
    frames: int
    sim_time_s: float
    wall_time_s: float
    final_pixel_rms: float | None
    final_position_error_m: float | None
    final_orientation_error_deg: float | None
    path_length_m: float | None
    path_ratio: float | None = None  # hand path over the straight line from start to end
    peak_ee_speed_m_s: float | None = None
    peak_joint_speed_rad_s: float | None = None
    min_manipulability: float | None = None
    marker_lost_s: float | None = None  # sim time the controller held: a marker not visible
    tracking_position_error_m: float | None = None  # median while the target moved
    tracking_max_position_error_m: float | None = None
    tracking_pixel_rms: float | None = None  # median while the target moved
    # At the last frame (ground truth, to name why a run failed): the joint nearest its limit,
    # and the hand marker's corner nearest the image border (negative: outside the image).
    final_joint_margin_deg: float | None = None
    final_hand_border_px: float | None = None
    # The first frame the arm pressed on the scenery (ground truth: sim time, and what it
    # touched, e.g. ``object``): a collision, which no servo law can undo by itself.
    first_contact_s: float | None = None
    contact_with: str | None = None
    detail: str = ""


def pose(values: list[float]) -> np.ndarray:
    return np.array(values).reshape(4, 4)


def square_orientation_error_deg(
    hand_pose: np.ndarray, target_pose: np.ndarray, oriented: bool = False
) -> float:
    """Rotation between the two marker frames, up to the square's 90° symmetry about its normal
    (the four corners look alike, so these four poses are indistinguishable to the camera);
    with ``oriented`` markers (``marker.orientation_cue``: corner 0 is marked) the whole
    rotation."""
    best = np.pi
    for k in range(1 if oriented else 4):
        turned = target_pose[:3, :3] @ kin.rot_z(k * np.pi / 2)
        best = min(best, kin.rotation_error_rad(hand_pose[:3, :3], turned))
    return float(np.degrees(best))


# A contact pressing with less than this is the physics engine's resting noise, not a collision.
CONTACT_MIN_N = 0.5


def first_contact(truths: dict[int, SimTruth], last_frame: int) -> tuple[float | None, str | None]:
    """When (sim s) and on what the arm first pressed on the scenery up to ``last_frame``
    (ground truth); ``(None, None)`` when it never did."""
    for k in sorted(truths):
        truth = truths[k]
        if k <= last_frame and truth.arm_contact_n >= CONTACT_MIN_N:
            return truth.header.sim_time_s, "+".join(truth.arm_contact_with)
    return None, None


def path_length_m(truths: dict[int, SimTruth], last_frame: int) -> float:
    points = [truths[k].ee_position_m for k in sorted(truths) if k <= last_frame]
    if len(points) < 2:
        return 0.0
    return float(np.sum(np.linalg.norm(np.diff(np.array(points), axis=0), axis=1)))


def marker_goal_error_m(truth: SimTruth, approach_height_m: float) -> float:
    """Distance of the green marker from its goal (the red marker raised), from ground truth."""
    goal = kin.goal_marker_pose(pose(truth.target_marker_pose), approach_height_m)
    return float(np.linalg.norm(pose(truth.hand_marker_pose)[:3, 3] - goal[:3, 3]))


def motion_metrics(truths: dict[int, SimTruth], last_frame: int) -> dict[str, float | None]:
    """Path ratio, peak hand speed, peak joint speed and least manipulability up to
    ``last_frame`` (ground truth, sampled once per camera frame)."""
    frames = [truths[k] for k in sorted(truths) if k <= last_frame]
    if len(frames) < 2:
        return {}
    t = np.array([f.header.sim_time_s for f in frames])
    ee = np.array([f.ee_position_m for f in frames])
    q = np.array([f.joint_position_rad for f in frames])
    dt = np.maximum(np.diff(t), 1e-9)
    steps = np.linalg.norm(np.diff(ee, axis=0), axis=1)
    straight = float(np.linalg.norm(ee[-1] - ee[0]))
    return {
        "path_ratio": float(np.sum(steps) / straight) if straight > 1e-6 else None,
        "peak_ee_speed_m_s": float(np.max(steps / dt)),
        "peak_joint_speed_rad_s": float(np.max(np.abs(np.diff(q, axis=0)) / dt[:, None])),
        "min_manipulability": float(
            min(kin.manipulability(kin.geometric_jacobian(qi)) for qi in q)
        ),
    }


def tracking_metrics(
    truths: dict[int, SimTruth],
    twists: dict[int, EndEffectorTwist],
    last_frame: int,
    moving: list[tuple[float, float]],
    approach_height_m: float,
    settle_s: float = 1.0,
) -> dict[str, float | None]:
    """Position error (median and max) and pixel error (median) while the target moved, from
    ``settle_s`` after each move began to its end (``moving``: (start, end) sim times)."""

    def in_window(t: float) -> bool:
        return any(start + settle_s <= t <= end for start, end in moving)

    seqs = [k for k in sorted(truths) if k <= last_frame and in_window(truths[k].header.sim_time_s)]
    if not seqs:
        return {}
    errors = np.array([marker_goal_error_m(truths[k], approach_height_m) for k in seqs])
    pixels = [twists[k].error_px_rms for k in seqs if k in twists and twists[k].servoing]
    return {
        "tracking_position_error_m": float(np.median(errors)),
        "tracking_max_position_error_m": float(np.max(errors)),
        "tracking_pixel_rms": float(np.median(pixels)) if pixels else None,
    }


def joint_margin_deg(q_rad: np.ndarray) -> float:
    """How far (degrees) the joint nearest one of its limits is from it."""
    margin = np.minimum(q_rad - kin.JOINT_LOWER_RAD, kin.JOINT_UPPER_RAD - q_rad)
    return float(np.degrees(np.min(margin)))


def border_margin_px(corners_px: np.ndarray, image_size_px: tuple[int, int]) -> float:
    """Distance of the corner nearest the image border from it (negative: outside)."""
    width, height = image_size_px
    u, v = corners_px[:, 0], corners_px[:, 1]
    return float(min(u.min(), v.min(), width - 1 - u.max(), height - 1 - v.max()))


def held_time_s(twists: dict[int, EndEffectorTwist], last_frame: int, period_s: float) -> float:
    """Sim time the controller held because a marker was not visible."""
    return period_s * sum(1 for k, tw in twists.items() if k <= last_frame and not tw.valid)


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
    period_s: float = 1.0 / 30.0,
    moving: list[tuple[float, float]] | None = None,
    image_size_px: tuple[int, int] | None = None,
    oriented_markers: bool = False,
) -> RunResult:
    """Result at ``last_frame`` (the frame whose twist decided the outcome). Errors compare the
    green marker with its goal: the red marker raised by ``approach_height_m``. ``period_s``:
    the camera period; ``moving``: (start, end) sim times of the target's moves;
    ``image_size_px``: (width, height), for how far the hand is from the border."""
    if reason != "converged" and not detail:
        raise ValueError(f"a {reason!r} result needs a detail saying why it did not converge")
    truth = truths.get(last_frame) if last_frame is not None else None
    twist = twists.get(last_frame) if last_frame is not None else None
    hand = pose(truth.hand_marker_pose) if truth else None
    target = (
        kin.goal_marker_pose(pose(truth.target_marker_pose), approach_height_m) if truth else None
    )
    extra: dict[str, float | None] = {}
    contact_with = None
    if truth is not None and last_frame is not None:
        extra.update(motion_metrics(truths, last_frame))
        extra.update(tracking_metrics(truths, twists, last_frame, moving or [], approach_height_m))
        extra["marker_lost_s"] = held_time_s(twists, last_frame, period_s)
        extra["final_joint_margin_deg"] = joint_margin_deg(np.array(truth.joint_position_rad))
        extra["first_contact_s"], contact_with = first_contact(truths, last_frame)
        if image_size_px is not None:
            extra["final_hand_border_px"] = border_margin_px(
                np.array(truth.hand_corners_px), image_size_px
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
        final_pixel_rms=twist.error_px_rms if twist and twist.servoing else None,
        final_position_error_m=(
            float(np.linalg.norm(hand[:3, 3] - target[:3, 3])) if truth else None
        ),
        final_orientation_error_deg=(
            square_orientation_error_deg(hand, target, oriented_markers) if truth else None
        ),
        path_length_m=path_length_m(truths, last_frame) if truth else None,
        contact_with=contact_with,
        detail=detail,
        **extra,
    )
