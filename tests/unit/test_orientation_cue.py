"""The orientation cue (marker.orientation_cue): vision labels a marker's corners physically,
by a small blue square inside it near its corner 0 (services/vision/cue.py).

Synthetic images here (pixel-centre sampling, exact plane depth); rendered ones, through the
simulator's World, in tests/test_orientation_cue_render.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from common import kinematics as kin
from common.camera import CameraIntrinsics, pixel_to_normalized, project
from common.config import ControllerConfig, JacobianMode, VisionConfig
from common.marker import Marker
from services.controller.arm import ArmReading
from services.controller.ibvs import IbvsController
from services.vision.cue import (
    CUE_HIDDEN,
    closest_roll,
    cue_fractions,
    cue_points_px,
    cued_corner,
    label_corners,
    physical_order,
)
from services.vision.measurement import measure_markers
from services.vision.tracking import DepthImage, TrackerState, observe

K = CameraIntrinsics.from_fov(640, 480, 57.0)
SHAPE = (K.height_px, K.width_px)
CFG = VisionConfig()
SIZE_M = 0.06
GREEN, RED, BLUE = (30, 180, 40), (200, 25, 25), (25, 60, 220)
BACKGROUND, BACKGROUND_Z_M = (128, 128, 128), 1.6


def marker_pose(centre_m: np.ndarray, turn_rad: float, tilt_rad: float = 0.3) -> np.ndarray:
    """A marker facing the camera (its z towards it), tilted about the camera's x and turned
    by ``turn_rad`` about its normal."""
    c, s = math.cos(turn_rad), math.sin(turn_rad)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    face_camera = np.diag([1.0, -1.0, -1.0])
    return kin.homogeneous(kin.rot_x(tilt_rad) @ face_camera @ turn, centre_m)


def cue_corners_m(pose: np.ndarray) -> np.ndarray:
    """The cue square's corners (camera frame), on the marker's face."""
    half = kin.CUE_SIDE_FRACTION * SIZE_M / 2
    centre = kin.cue_centre_in_marker(SIZE_M)
    local = [
        centre + np.array([a * half, b * half, 0.0])
        for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))
    ]
    return (pose @ np.column_stack([local, np.ones(4)]).T).T[:, :3]


def inside(corners_px: np.ndarray) -> np.ndarray:
    """Pixels whose centre is inside a convex polygon (either turn)."""
    c = np.asarray(corners_px, dtype=float)
    e = np.roll(c, -1, axis=0) - c
    turn = np.sign(np.sum(e[:, 0] * np.roll(e, -1, 0)[:, 1] - e[:, 1] * np.roll(e, -1, 0)[:, 0]))
    v, u = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]].astype(float)
    mask = np.ones(SHAPE, bool)
    for a, d in zip(c, e, strict=True):
        mask &= turn * (d[0] * (v - a[1]) - d[1] * (u - a[0])) >= 0
    return mask


def plane_depth(points_m: np.ndarray) -> np.ndarray:
    n = np.cross(points_m[1] - points_m[0], points_m[3] - points_m[0])
    v, u = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]].astype(float)
    xy = pixel_to_normalized(np.column_stack([u.ravel(), v.ravel()]), K)
    return (n @ points_m[0] / (np.column_stack([xy, np.ones(len(xy))]) @ n)).reshape(SHAPE)


def render(
    hand_turn_rad: float,
    cue: bool = True,
    cue_z_offset_m: float = 0.0,
    target_turn_rad: float = 0.4,
    target_cue_hidden: bool = False,
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Both markers (each turned by its angle), with their cues: RGB, depth (the cue
    ``cue_z_offset_m`` nearer than its marker) and the true corners (px, physical order);
    ``target_cue_hidden``: a grey patch where the target's cue is."""
    rgb = np.empty((*SHAPE, 3), np.uint8)
    rgb[:] = BACKGROUND
    depth = np.full(SHAPE, BACKGROUND_Z_M, np.float32)
    truth = {}
    poses = {
        "hand": (marker_pose(np.array([-0.08, 0.0, 0.5]), hand_turn_rad), GREEN),
        "target": (marker_pose(np.array([0.08, 0.02, 0.55]), target_turn_rad), RED),
    }
    for name, (pose, colour) in poses.items():
        corners_m = kin.marker_corners(pose, SIZE_M)
        truth[name] = project(corners_m, K)
        region = inside(truth[name])
        rgb[region] = colour
        depth[region] = plane_depth(corners_m)[region]
        if cue:
            patch = inside(project(cue_corners_m(pose), K))
            rgb[patch] = (90, 90, 95) if name == "target" and target_cue_hidden else BLUE
            depth[patch] -= cue_z_offset_m
    return rgb, depth, truth


def labels_of(measured_px: np.ndarray, truth_px: np.ndarray) -> list[int]:
    """The true corner each measured corner lies on (within 0.5 px)."""
    d = np.linalg.norm(measured_px[:, None, :] - truth_px[None, :, :], axis=2)
    assert np.all(d.min(axis=1) < 0.5), d
    return d.argmin(axis=1).tolist()


# --- the pieces ---------------------------------------------------------------------------------
def test_physical_order_keeps_the_first_corner_and_reverses_the_turn() -> None:
    clockwise = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    assert physical_order(clockwise).tolist() == [[0, 0], [0, 10], [10, 10], [10, 0]]


def test_cue_points_lie_a_quarter_of_the_diagonal_from_each_corner() -> None:
    square = np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 40.0], [0.0, 40.0]])
    expected = [[10.0, 10.0], [30.0, 10.0], [30.0, 30.0], [10.0, 30.0]]
    np.testing.assert_allclose(cue_points_px(square), expected, atol=1e-4)
    # in perspective the homography moves them off the straight 1/4 point, towards the far side
    _, _, truth = render(0.0)
    pose = marker_pose(np.array([-0.08, 0.0, 0.5]), 0.0)
    true_centre = project((pose @ np.append(kin.cue_centre_in_marker(SIZE_M), 1.0))[None, :3], K)
    np.testing.assert_allclose(cue_points_px(truth["hand"])[0], true_centre[0], atol=1e-3)


@pytest.mark.parametrize(
    ("fractions", "expected"),
    [
        ([0.0, 0.9, 0.0, 0.1], 1),
        ([1.0, 0.0, 0.0, 0.0], 0),
        ([0.0, 0.0, 0.0, 0.0], None),  # hidden
        ([0.3, 0.3, 0.0, 0.0], None),  # nowhere clearly
        ([0.8, 0.0, 0.7, 0.0], None),  # two: not this cue
        ([0.8, 0.0, 0.3, 0.0], None),  # another corner half covered: not sure
    ],
)
def test_cued_corner(fractions: list[float], expected: int | None) -> None:
    assert cued_corner(np.array(fractions)) == expected


def test_closest_roll_carries_the_labels_on() -> None:
    square = np.array([[0.0, 0.0], [0.0, 10.0], [10.0, 10.0], [10.0, 0.0]])
    previous = np.roll(square, -3, axis=0) + 0.5
    np.testing.assert_array_equal(closest_roll(square, previous), np.roll(square, -3, axis=0))


# --- labelling a frame --------------------------------------------------------------------------
@pytest.mark.parametrize("turn_deg", [0, 30, 90, 135, 180, 225, 270, 320])
def test_with_the_cue_corner_i_is_the_true_corner_i_at_any_turn(turn_deg: int) -> None:
    rgb, depth, truth = render(math.radians(turn_deg))
    measured = measure_markers(rgb, depth, K, CFG, orientation_cue=True)
    for name in ("hand", "target"):
        assert measured[name].visible, measured[name].reason
        assert labels_of(measured[name].corners_px, truth[name]) == [0, 1, 2, 3]


def test_without_the_cue_a_half_turn_is_seen_as_none() -> None:
    """The old labelling (by place in the image) documented: a hand turned by 180° gets the
    labels of the unturned one, rolled by two corners (and in the image's clockwise turn)."""
    labels = {}
    for turn_deg in (0, 180):
        rgb, depth, truth = render(math.radians(turn_deg), cue=False)
        hand = measure_markers(rgb, depth, K, CFG)["hand"]
        labels[turn_deg] = labels_of(hand.corners_px, truth["hand"])
    assert labels[180] == [(i + 2) % 4 for i in labels[0]]
    assert labels[0] != [0, 1, 2, 3]  # clockwise: the reverse turn of marker_corners


def test_cue_off_ignores_a_cue_in_the_image() -> None:
    """Off, vision does exactly what it did before: the cue (a hole in the mask) does not
    change the corners, which are in the image's clockwise order."""
    with_cue = measure_markers(*render(math.radians(180))[:2], K, CFG)
    plain = measure_markers(*render(math.radians(180), cue=False)[:2], K, CFG)
    for name in ("hand", "target"):
        np.testing.assert_allclose(with_cue[name].corners_px, plain[name].corners_px, atol=1e-9)


def test_depth_ignores_the_cue_pixels() -> None:
    """The cue is a hole in the colour mask: a cue standing proud of its marker (by less than
    the plane fit's 1 mm outlier floor, so that it would tilt the plane if it were sampled)
    leaves the corner depths as they are with a flush one."""
    rgb, depth, _ = render(math.radians(135))
    flush = measure_markers(rgb, depth, K, CFG, orientation_cue=True)
    rgb, depth, _ = render(math.radians(135), cue_z_offset_m=0.0005)
    proud = measure_markers(rgb, depth, K, CFG, orientation_cue=True)
    for name in ("hand", "target"):
        assert proud[name].visible and not proud[name].occluded
        np.testing.assert_allclose(proud[name].depth_m, flush[name].depth_m, atol=1e-9)


def hide_cue(rgb: np.ndarray, name: str, turn_rad: float) -> None:
    """Paint a grey patch over a marker's cue, inside its square (its outline stays whole)."""
    pose = marker_pose(np.array([-0.08, 0.0, 0.5]), turn_rad)
    assert name == "hand"
    centre = kin.cue_centre_in_marker(SIZE_M)
    half = 0.9 * kin.CUE_SIDE_FRACTION * SIZE_M  # a patch twice the cue's size
    local = [
        centre + np.array([a * half, b * half, 0.0])
        for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))
    ]
    patch = project((pose @ np.column_stack([local, np.ones(4)]).T).T[:, :3], K)
    rgb[inside(patch)] = (90, 90, 95)


def fresh(rgb: np.ndarray, depth: np.ndarray) -> DepthImage:
    return DepthImage(depth, K, 0.0)


def test_a_hidden_cue_makes_a_new_marker_unusable_and_a_tracked_one_keep_its_labels() -> None:
    turn = math.radians(180)
    rgb, depth, truth = render(turn)
    covered = rgb.copy()
    hide_cue(covered, "hand", turn)
    # first sight with the cue hidden: corner 0 cannot be told
    first, _ = observe(covered, K, fresh(covered, depth), CFG, SIZE_M, TrackerState(), 0.0, True)
    assert first["hand"].state == "partial" and first["hand"].reason == CUE_HIDDEN
    assert not first["hand"].usable and first["target"].visible
    # labelled by its cue, then hidden: carried on by continuity
    seen, state = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, TrackerState(), 0.0, True)
    assert labels_of(seen["hand"].corners_px, truth["hand"]) == [0, 1, 2, 3]
    carried, state = observe(covered, K, fresh(covered, depth), CFG, SIZE_M, state, 1 / 30, True)
    assert carried["hand"].visible
    assert labels_of(carried["hand"].corners_px, truth["hand"]) == [0, 1, 2, 3]
    # lost for a frame (cue hidden and no continuity), then back with its cue still hidden
    blank = np.empty_like(rgb)
    blank[:] = BACKGROUND
    gone, state = observe(blank, K, fresh(blank, depth), CFG, SIZE_M, state, 2 / 30, True)
    assert gone["hand"].state == "lost"
    back, _ = observe(covered, K, fresh(covered, depth), CFG, SIZE_M, state, 3 / 30, True)
    assert back["hand"].reason == CUE_HIDDEN


@pytest.mark.parametrize("turn_while_lost_deg", [0, 90, 180])
def test_a_target_back_from_lost_with_its_cue_hidden_is_not_labelled_from_memory(
    turn_while_lost_deg: int,
) -> None:
    """Lost, then back whole with its cue hidden: its labels cannot come from the frame before
    (it was not there) and must not come from its last whole view (it may have turned since):
    unusable, as a marker first seen with its cue hidden is. It was fitted with the old labels,
    a quarter or half turn off, and the controller paired corner i with the wrong corner."""
    rgb, depth, _ = render(0.0)
    seen, state = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, TrackerState(), 0.0, True)
    assert seen["target"].visible
    blank = np.empty_like(rgb)
    blank[:] = BACKGROUND
    empty = np.full(SHAPE, BACKGROUND_Z_M, np.float32)
    gone, state = observe(blank, K, fresh(blank, empty), CFG, SIZE_M, state, 1 / 30, True)
    assert gone["target"].state == "lost"
    turn = 0.4 + math.radians(turn_while_lost_deg)
    rgb, depth, _ = render(0.0, target_turn_rad=turn, target_cue_hidden=True)
    back, _ = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, state, 2 / 30, True)
    assert not back["target"].usable and back["target"].reason == CUE_HIDDEN, back["target"]


def test_a_wrong_labelling_is_corrected_by_the_cue_while_tracking() -> None:
    rgb, depth, truth = render(math.radians(100))
    wrong = np.roll(truth["hand"], 2, axis=0)  # as if a half turn had been folded away
    measured = measure_markers(rgb, depth, K, CFG, {"hand": wrong}, orientation_cue=True)
    assert labels_of(measured["hand"].corners_px, truth["hand"]) == [0, 1, 2, 3]


def cut_through_cue(rgb: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """A closer bar over the target's cued corner, its edge across the cue just past the cue's
    centre (where vision samples it): what is left of the cue opens into the red blob's
    outline as a notch. Returns the mask of the bar."""
    pose = marker_pose(np.array([0.08, 0.02, 0.55]), 0.4)
    centre_m = (pose @ np.append(kin.cue_centre_in_marker(SIZE_M), 1.0))[:3]
    cue_px = project(centre_m[None, :], K)[0]
    square_px = project(kin.marker_corners(pose, SIZE_M), K)
    out = cue_px - square_px.mean(axis=0)
    out /= np.linalg.norm(out)
    side_px = np.linalg.norm(square_px[1] - square_px[0])
    v, u = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]].astype(float)
    edge_px = 0.3 * kin.CUE_SIDE_FRACTION * side_px  # past the cue's centre, within the cue
    bar = (u - cue_px[0]) * out[0] + (v - cue_px[1]) * out[1] > edge_px
    rgb[bar] = (90, 90, 95)
    depth[bar] = 0.45
    return bar


@pytest.mark.parametrize("seen_before", [False, True])
def test_an_occluder_across_the_cue_leaves_the_target_fitted_and_labelled(
    seen_before: bool,
) -> None:
    """The cue's pixels count as the marker's in the outline of a partly hidden marker: the
    notch the cut cue leaves is not one of the square's sides (the domain study's start
    c0018_d09, its forearm over the target's cued corner, was never fitted before)."""
    rgb, depth, truth = render(0.0)
    state = TrackerState()
    if seen_before:  # fitted on its remembered plane
        _, state = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, state, 0.0, True)
    cut_through_cue(rgb, depth)
    seen, _ = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, state, 1 / 30, True)
    target = seen["target"]
    assert target.state == "partial" and target.fitted and target.usable, target.reason
    assert labels_of(target.corners_px, truth["target"]) == [0, 1, 2, 3]


# --- the controller -----------------------------------------------------------------------------
def test_with_oriented_markers_the_controller_pairs_corner_i_with_corner_i() -> None:
    """A hand turned by 180° about the optical axis: by least turn (plain squares) its corners
    are paired two off, as if it were not turned; with oriented markers corner i goes to
    corner i, and the error is the half turn's."""
    h = SIZE_M / 2
    square = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    target = square + np.array([0.0, 0.05, 0.55])
    hand = -square * np.array([1.0, 1.0, 0.0]) + np.array(
        [0.02, 0.03, 0.50]
    )  # turned by 180° about the z axis

    def obs(points: np.ndarray) -> Marker:
        return Marker.seen_at(points, K)

    turns = {}
    for oriented in (False, True):
        ctrl = IbvsController(ControllerConfig(mode=JacobianMode.POINTS3D), np.eye(4))
        ctrl.oriented_markers = oriented
        out = ctrl.step(obs(hand), obs(target), K, ArmReading(hand.mean(axis=0)))
        turns[oriented] = (ctrl.pairing, out)
    assert turns[False][0] == 2 and turns[True][0] == 0
    assert turns[True][1].valid and turns[False][1].valid
    half_turn_px = project(hand, K) - project(target, K)  # corner i to corner i
    assert turns[True][1].error_px_rms == pytest.approx(np.sqrt(np.mean(half_turn_px**2)))
    assert turns[False][1].error_px_rms < 0.5 * turns[True][1].error_px_rms


@pytest.mark.parametrize(
    "corners",
    [
        [[-50.0, 200.0], [10.0, 200.0], [10.0, 260.0], [-50.0, 260.0]],  # 10 px in, left
        [[630.0, 200.0], [690.0, 200.0], [690.0, 260.0], [630.0, 260.0]],  # right
        [[300.0, 470.0], [360.0, 470.0], [360.0, 530.0], [300.0, 530.0]],  # bottom
    ],
)
def test_a_fitted_square_whose_cue_points_are_all_outside_the_image_shows_no_cue(corners) -> None:
    """A target fitted from a strip at the border has every cue point beyond the image: no
    cue seen, and no empty crop handed to OpenCV (it raised, and ended vision)."""
    rgb = np.full((480, 640, 3), 128, np.uint8)
    square = np.array(corners)
    assert np.array_equal(cue_fractions(rgb, square, VisionConfig()), np.zeros(4))
    label_corners(rgb, square, None, VisionConfig())  # labels it without the cue, no error
