"""Partly hidden markers fitted without a remembered view (services/vision/own_depth.py,
tracking.py): the plane from the frame's own depth, the first pose from the blob. A target
hidden in part from the first frame on, a hand whose arm borders its marker, and fits that
must be refused; and the controller servoing on a fitted hand. Synthetic frames rendered as
in test_vision_features."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from common.config import ControllerConfig, VisionConfig
from common.marker import Marker as SeenMarker
from services.controller.arm import ArmReading
from services.controller.ibvs import IbvsController
from services.vision.own_depth import blob_plane, square_from_outline
from services.vision.partial import outline
from services.vision.quad import order_corners
from services.vision.tracking import DepthImage, TrackerState, observe
from tests.unit.test_vision_features import (
    GREEN,
    RED,
    K,
    Marker,
    match_order,
    polygon_mask,
    render,
    rotation,
    square_3d,
)

CFG = VisionConfig()
SIZE_M = 0.06
SKIN = (235, 228, 218)  # the arm: low saturation, no marker colour


def fresh(depth: np.ndarray) -> DepthImage:
    return DepthImage(depth, K, 0.0)


def put_bar(rgb: np.ndarray, depth: np.ndarray, corners_px: np.ndarray, z_m: float) -> None:
    """A skin-coloured quadrilateral ``corners_px`` (4, 2) at depth ``z_m``, in front."""
    inside = polygon_mask(corners_px)
    rgb[inside] = SKIN
    depth[inside] = z_m


def corner_error_px(found_px: np.ndarray, true_px: np.ndarray) -> float:
    return float(np.abs(match_order(found_px, true_px) - order_corners(true_px)).max())


def hand_and_target(target_rot: np.ndarray) -> tuple[Marker, Marker]:
    hand = Marker(square_3d(np.array([-0.12, -0.05, 0.45]), SIZE_M, rotation(0.2, 0.5, 0.1)), GREEN)
    target = Marker(square_3d(np.array([0.06, 0.04, 0.5]), SIZE_M, target_rot), RED)
    return hand, target


def bar_across(corners_px: np.ndarray, fraction: float, slope: float) -> np.ndarray:
    """A bar over the right-hand ``fraction`` of the square's horizontal extent, its left edge
    slanted by ``slope`` (columns per row), reaching well past the square."""
    u0, u1 = corners_px[:, 0].min(), corners_px[:, 0].max()
    v0, v1 = corners_px[:, 1].min() - 15, corners_px[:, 1].max() + 15
    left = u1 - fraction * (u1 - u0)
    mid = (v0 + v1) / 2
    return np.array(
        [
            [left + slope * (v0 - mid), v0],
            [u1 + 40, v0],
            [u1 + 40, v1],
            [left + slope * (v1 - mid), v1],
        ]
    )


@pytest.mark.parametrize(
    "rot, fraction, slope",
    [
        (rotation(0.3, 0.8, 0.4), 0.35, 0.0),
        (rotation(0.3, 0.8, 0.4), 0.3, 0.4),
        (rotation(-0.2, 0.6, 1.1), 0.4, -0.3),
        (rotation(0.1, 0.9, -0.3), 0.25, 0.2),
    ],
)
def test_a_target_never_seen_whole_is_fitted_from_its_own_depth(
    rot: np.ndarray, fraction: float, slope: float
) -> None:
    """A closer bar over part of the target from the first frame on: no remembered view, so
    the plane comes from the visible blob's depth and the pose from its outline."""
    hand, target = hand_and_target(rot)
    rgb, depth = render([hand, target])
    put_bar(rgb, depth, bar_across(target.corners_px, fraction, slope), 0.40)
    measured, state = observe(rgb, K, fresh(depth), CFG, SIZE_M, TrackerState())
    m = measured["target"]
    assert m.state == "partial" and m.fitted and m.usable and m.occluded, m.reason
    err = corner_error_px(m.corners_px, target.corners_px)
    assert err < 0.5, f"fitted corners off by {err:.2f} px"
    order = [int(np.argmin(np.sum((target.corners_px - c) ** 2, axis=1))) for c in m.corners_px]
    np.testing.assert_allclose(m.depth_m, target.points_m[order, 2], atol=1.5e-3)
    np.testing.assert_allclose(m.points_m, target.points_m[order], atol=2e-3)
    assert "target" in state.memory  # the fitted view is remembered with its plane


def test_the_first_pose_from_an_outline_is_near_the_square() -> None:
    """The guess the fit starts from (turn from the true edges' directions, centre from the
    sides they show) is within a few degrees and millimetres of the hidden square's pose."""
    _, target = hand_and_target(rotation(0.3, 0.8, 0.4))
    rgb, depth = render([target])
    put_bar(rgb, depth, bar_across(target.corners_px, 0.4, 0.3), 0.40)
    mask = np.where(np.all(rgb == RED, axis=2), 255, 0).astype(np.uint8)
    plane = blob_plane(mask, depth, K, K)
    assert plane is not None
    occluder = ((depth < 0.45) * 255).astype(np.uint8)
    points, true_edge = outline(mask, occluder)
    square = square_from_outline(plane, points, true_edge, K, SIZE_M)
    assert square is not None
    axis_u = target.points_m[1] - target.points_m[0]
    axis_u /= np.linalg.norm(axis_u)
    folded = np.arccos(np.clip(abs(axis_u @ square.axis_u), 0.0, 1.0))
    turn_deg = np.degrees(min(folded, np.pi / 2 - folded))
    assert turn_deg < 3.0, f"first turn off by {turn_deg:.1f}°"
    offset_mm = 1e3 * np.linalg.norm(square.centre_m - target.points_m.mean(axis=0))
    assert offset_mm < 3.0, f"first centre off by {offset_mm:.1f} mm"


def hand_with_arm(arm_overlap_px: float) -> tuple[Marker, np.ndarray, np.ndarray]:
    """The hand's marker with its forearm, closer to the camera, along its lower-right side:
    touching it (``arm_overlap_px`` 0) or shaving that much off its corner."""
    hand = Marker(square_3d(np.array([-0.05, 0.0, 0.5]), SIZE_M, rotation(0.4, 0.5, 0.2)), GREEN)
    target = Marker(square_3d(np.array([0.1, 0.06, 0.55]), SIZE_M, rotation(0.3, 0.8, 0.4)), RED)
    rgb, depth = render([target])
    c = hand.corners_px
    right = int(np.argmax(c[:, 0]))  # the arm leaves the marker at its rightmost corner
    tip = c[right] - arm_overlap_px * (c[right] - c.mean(axis=0)) / np.linalg.norm(
        c[right] - c.mean(axis=0)
    )
    arm = tip + np.array([[0.0, -25.0], [120.0, -25.0], [120.0, 25.0], [0.0, 25.0]])
    put_bar(rgb, depth, arm, 0.42)
    inside = polygon_mask(hand.corners_px) & ~polygon_mask(arm)
    rgb[inside] = GREEN
    depth[inside] = render([hand])[1][inside]
    return hand, rgb, depth


@pytest.mark.parametrize("overlap_px", [0.0, 4.0])
def test_a_hand_bordered_by_its_arm_is_fitted_and_usable(overlap_px: float) -> None:
    hand, rgb, depth = hand_with_arm(overlap_px)
    measured, _ = observe(rgb, K, fresh(depth), CFG, SIZE_M, TrackerState())
    m = measured["hand"]
    assert m.state == "partial" and m.occluded, (m.state, m.reason)
    assert m.fitted and m.usable
    err = corner_error_px(m.corners_px, hand.corners_px)
    assert err < 0.5, f"fitted corners off by {err:.2f} px"


def test_half_a_target_with_one_true_edge_is_refused() -> None:
    """Bars over the right half and over the top and bottom of the left half: the blob's only
    true edge is part of its left side, which cannot pin the square down."""
    target = Marker(square_3d(np.array([0.0, 0.0, 0.5]), SIZE_M, np.eye(3)), RED)
    rgb, depth = render([target])
    u0, u1 = target.corners_px[:, 0].min(), target.corners_px[:, 0].max()
    v0, v1 = target.corners_px[:, 1].min(), target.corners_px[:, 1].max()
    mid, side = (u0 + u1) / 2, v1 - v0
    for box in (
        (mid, v0 - 20, u1 + 20, v1 + 20),
        (u0 - 20, v0 - 20, mid + 1, v0 + 0.2 * side),
        (u0 - 20, v1 - 0.2 * side, mid + 1, v1 + 20),
    ):
        a0, b0, a1, b1 = box
        put_bar(rgb, depth, np.array([[a0, b0], [a1, b0], [a1, b1], [a0, b1]]), 0.40)
    measured, _ = observe(rgb, K, fresh(depth), CFG, SIZE_M, TrackerState())
    m = measured["target"]
    assert m.state == "partial" and m.occluded and not m.fitted and not m.usable, m.reason


def test_a_hand_half_hidden_is_not_fitted() -> None:
    """Two of the hand's sides show, enough to fit a target by, but the hand is servoed on:
    it is fitted only when most of its marker is seen."""
    hand = Marker(square_3d(np.array([-0.05, 0.0, 0.5]), SIZE_M, rotation(0.4, 0.5, 0.2)), GREEN)
    rgb, depth = render([hand])
    put_bar(rgb, depth, bar_across(hand.corners_px, 0.45, 0.3), 0.40)
    measured, _ = observe(rgb, K, fresh(depth), CFG, SIZE_M, TrackerState())
    m = measured["hand"]
    assert m.state == "partial" and m.occluded and not m.fitted and not m.usable, m.reason


def test_the_controller_servoes_on_a_fitted_hand_and_holds_on_an_unfitted_one() -> None:
    hand, rgb, depth = hand_with_arm(0.0)
    measured, _ = observe(rgb, K, fresh(depth), CFG, SIZE_M, TrackerState())
    seen_hand, seen_target = measured["hand"], measured["target"]
    assert seen_hand.fitted and seen_target.visible
    ctrl = IbvsController(ControllerConfig(acquire=False), np.eye(4))
    out = ctrl.step(seen_hand, seen_target, K, ArmReading(hand.points_m.mean(axis=0)))
    assert out.valid and np.any(out.twist_base_ee)
    unfitted = SeenMarker.unseen("partial", "occluded", occluded=True)
    out = ctrl.step(unfitted, seen_target, K, ArmReading(hand.points_m.mean(axis=0)))
    assert not out.valid and out.hold_reason == "hand partial"
    assert not replace(seen_hand, fitted=False).usable
