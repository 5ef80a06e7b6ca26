"""The controller's one step as a pure function of its state: a frame's wire features and the
joint encoders → the end-effector twist.

The controller node and the in-process pipeline (services/pipeline.py) both call it. The state
is the :class:`IbvsController` itself (a dataclass: frozen Jacobian, convergence counter,
target memory...). It uses only what the camera and the encoders give, plus the *assumed*
camera pose held by the controller (the calibration); never the simulator's ground truth.
"""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np

from common import kinematics as kin
from common.config import ClearanceCorrection
from common.kinematics import FloatArray
from common.marker import Marker
from common.messages import PIXEL_LIMIT_PX, EndEffectorTwist, Features, Header
from services.controller import clearance, forearm
from services.controller.arm import ArmReading
from services.controller.constrained import least_feature_change
from services.controller.ibvs import ControlOutput, IbvsController
from services.controller.twist import (
    camera_points_to_base,
    clamp_twist,
    twist_matrix_base_ee_to_cam,
)


def control_step(
    controller: IbvsController, features: Features, q_rad: FloatArray | list[float]
) -> ControlOutput:
    """One control step (``controller`` advances) on ``features`` with the joints at ``q_rad``
    (the joint state of the same frame)."""
    arm = ArmReading.from_joints(q_rad)
    out = controller.step(
        Marker.from_wire(features.hand),
        Marker.from_wire(features.target),
        features.intrinsics,
        arm,
        features.header.sim_time_s,
    )
    return above_the_target(controller, out, arm)


def above_the_target(
    controller: IbvsController, out: ControlOutput, arm: ArmReading
) -> ControlOutput:
    """``out`` with its twist kept from lowering the hand box onto the object's top face
    and from carrying the forearm onto the object (:func:`object_bounds`): the law's twist
    changed where its features notice it least (:mod:`services.controller.constrained`), then
    lifted by what that left short (with ``controller.clearance_correction = "lift"``, or a
    twist not the law's: lifted alone), and a bound rising does not help met by the nearest
    twist (:func:`.clearance.lift_then_nearest`); unchanged while holding or before any
    view."""
    cfg = controller.config
    last = controller.target_memory.last
    if not out.valid or last is None:
        return out
    # The red corners in the base frame once a frame: the top face's plane and its square.
    corners, plane = target_top(last.points_m, controller.t_base_cam)
    rows, bounds = object_bounds(controller, arm, plane, corners)
    twist = out.twist_base_ee
    if len(bounds) == 0 or float((bounds - rows @ twist).max()) <= 0.0:
        return out
    least_change = cfg.clearance_correction is ClearanceCorrection.LEAST_FEATURE_CHANGE
    if least_change and out.control_matrix is not None:  # the law's twist: its W, only now
        w_cam = kin.pinv(out.control_matrix)
        w_base = w_cam @ twist_matrix_base_ee_to_cam(controller.t_base_cam, arm.p_ee_base_m)
        twist, _ = least_feature_change(twist, rows, bounds, w_base)
    # What the sweeps left short, or the whole correction of a twist not the law's.
    twist, _ = clearance.lift_then_nearest(twist, rows, bounds, plane.normal)
    twist = clamp_twist(twist, cfg.max_linear_m_s, cfg.max_angular_rad_s)
    return replace(out, twist_base_ee=twist, lifted=True)


def target_top(
    points_cam_m: FloatArray, t_base_cam: FloatArray
) -> tuple[FloatArray, clearance.Plane]:
    """The red marker's corners (4×3, camera frame) in the base frame through the camera pose,
    and their plane (the object's top face's); the last ones made (read-only) when the corners
    and the pose are the same to the bit: a still target is measured so frame after frame (or
    remembered)."""
    points = np.ascontiguousarray(points_cam_m, dtype=float)
    pose = np.ascontiguousarray(t_base_cam, dtype=float)
    return _target_top_of_bytes(points.tobytes(), pose.tobytes())


@functools.lru_cache(maxsize=4)
def _target_top_of_bytes(
    points_cam_m: bytes, t_base_cam: bytes
) -> tuple[FloatArray, clearance.Plane]:
    """:func:`target_top` of float64 arrays given as their bytes (4×3, 4×4)."""
    pose = np.frombuffer(t_base_cam, dtype=float).reshape(4, 4)
    corners = camera_points_to_base(np.frombuffer(points_cam_m, dtype=float).reshape(4, 3), pose)
    plane = clearance.plane_of_corners(corners, pose[:3, 3])
    for array in (corners, plane.point_m, plane.normal):
        array.setflags(write=False)
    return corners, plane


def object_bounds(
    controller: IbvsController,
    arm: ArmReading,
    plane: clearance.Plane,
    target_corners_base_m: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Every bound a twist must keep near the object, as ``rows · twist ≥ bounds``: the hand
    box's corners above its top face's plane (:mod:`services.controller.clearance`), the
    forearm off the object (:mod:`services.controller.forearm`, its margin capped by its
    clearance at the goal posture), the face the plane of the red marker's corners (base
    frame); none for what is not kept (its setting off, no object model,
    an encoders' reading without the form it needs)."""
    cfg = controller.config
    parts = []
    if cfg.keep_above_target and arm.t_base_ee is not None:
        p_ee = arm.p_ee_base_m
        corners = clearance.hand_box_corners_ee() @ arm.t_base_ee[:3, :3].T + p_ee
        parts.append(
            clearance.clearance_bounds(
                corners, p_ee, plane, cfg.hand_clearance_m, cfg.clearance_rate_1_s
            )
        )
    side = controller.object_side_m
    if cfg.keep_forearm_off_object and side is not None and arm.frames is not None:
        face = forearm.top_face(plane, target_corners_base_m, side)
        d_min = kin.LIMB_RADIUS_M + cfg.forearm_clearance_m
        goal_q = controller.goal_posture_rad()
        rate = cfg.clearance_rate_1_s
        parts.append(forearm.forearm_bounds(arm.frames, face, d_min, rate, goal_q))
    if not parts:
        return np.zeros((0, 6)), np.zeros(0)
    return np.vstack([rows for rows, _ in parts]), np.concatenate([b for _, b in parts])


def twist_message(out: ControlOutput, header: Header, mode: str) -> EndEffectorTwist:
    """What the controller publishes for one step."""
    return EndEffectorTwist(
        header=header,
        linear_m_s=out.twist_base_ee[:3].tolist(),
        angular_rad_s=out.twist_base_ee[3:].tolist(),
        valid=out.valid,
        hold_reason=out.hold_reason,
        mode=mode,
        error_px_rms=out.error_px_rms,
        converged=out.converged,
        lifted=out.lifted,
        goal_px=wire_corners(out.goal_px),
    )


def wire_corners(corners_px: FloatArray | None) -> list[list[float]] | None:
    """Corners as the wire carries them; None for none, or for corners the wire cannot carry
    (a remembered goal carried far out of the image: only the view reads them)."""
    if corners_px is None:
        return None
    corners = np.asarray(corners_px, dtype=float)
    if not np.all(np.abs(corners) <= PIXEL_LIMIT_PX):  # NaN too
        return None
    return corners.tolist()
