"""Vision over time (services/vision/tracking.py, partial.py, occlusion.py) on synthetic frames:
partly hidden targets fitted from their edges, hidden versus gone, depth between depth images,
depth at a lower resolution, occlusion seen past the depth camera's invalid band."""

from __future__ import annotations

import numpy as np
import pytest

from common.camera import CameraIntrinsics, pixel_to_normalized, project
from common.config import VisionConfig
from services.vision import partial
from services.vision.depth import fit_inverse_depth_plane, registered_mask
from services.vision.measurement import measure_markers
from services.vision.occlusion import hidden_behind, occluder_fraction
from services.vision.quad import order_corners
from services.vision.tracking import DepthImage, TrackerState, observe
from tests.unit.test_vision_features import (
    GREEN,
    RED,
    SHAPE,
    K,
    Marker,
    match_order,
    plane_depth_m,
    polygon_mask,
    render,
    rotation,
    square_3d,
)

CFG = VisionConfig()
SIZE_M = 0.06
SKIN = (235, 228, 218)  # the hand's box: low saturation, no marker colour


def scene() -> tuple[Marker, Marker]:
    """The hand's green square to the left, the red target tilted like the table top."""
    target = Marker(square_3d(np.array([0.06, 0.04, 0.5]), SIZE_M, rotation(0.3, 0.8, 0.4)), RED)
    hand = Marker(square_3d(np.array([-0.12, -0.05, 0.45]), SIZE_M, rotation(0.2, 0.5, 0.1)), GREEN)
    return hand, target


def fresh(rgb: np.ndarray, depth: np.ndarray) -> DepthImage:
    return DepthImage(depth, K, 0.0)


def cover(rgb: np.ndarray, depth: np.ndarray, box: tuple[int, int, int, int], z_m: float) -> None:
    """Put a skin-coloured box (rows r0:r1, columns c0:c1) at depth ``z_m`` in front."""
    r0, r1, c0, c1 = box
    rgb[r0:r1, c0:c1] = SKIN
    depth[r0:r1, c0:c1] = z_m


def first_view() -> tuple[TrackerState, Marker, Marker]:
    hand, target = scene()
    rgb, depth = render([hand, target])
    measured, state = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, TrackerState())
    assert measured["target"].visible and measured["hand"].visible
    return state, hand, target


def box_over(corners_px: np.ndarray, fraction: float) -> tuple[int, int, int, int]:
    """A box covering the right-hand ``fraction`` of the square's horizontal extent."""
    u0, u1 = corners_px[:, 0].min(), corners_px[:, 0].max()
    v0, v1 = corners_px[:, 1].min(), corners_px[:, 1].max()
    left = int(u1 - fraction * (u1 - u0))
    return int(v0) - 10, int(v1) + 10, left, int(u1) + 10


def test_a_partly_hidden_target_is_fitted_from_its_visible_edges() -> None:
    state, hand, target = first_view()
    rgb, depth = render([hand, target])
    cover(rgb, depth, box_over(target.corners_px, 0.4), 0.40)
    measured, _ = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, state, 1 / 30)
    m = measured["target"]
    assert m.state == "partial" and m.fitted and m.usable and m.occluded, m.reason
    err = np.abs(match_order(m.corners_px, target.corners_px) - order_corners(target.corners_px))
    assert err.max() < 0.3, f"fitted corners off by {err.max():.2f} px"
    np.testing.assert_allclose(np.sort(m.depth_m), np.sort(target.points_m[:, 2]), atol=1e-3)


@pytest.mark.parametrize("occluder_depth_m", [0.0, float("nan")])
@pytest.mark.parametrize("cut", [0.3, 0.5])
def test_a_target_cut_by_something_the_depth_image_misses_is_not_called_visible(
    cut: float, occluder_depth_m: float
) -> None:
    """Something in front with no valid depth (nearer than the Kinect's range, dark): no
    closer surface shows round the blob, whose colour quadrilateral is the cut square. Its
    sides are not the marker's, so it is not a whole square: fitted from its edges, or left
    partial, never `visible` with corners tens of pixels off."""
    state, hand, target = first_view()
    rgb, depth = render([hand, target])
    cover(rgb, depth, box_over(target.corners_px, cut), occluder_depth_m)
    measured, _ = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, state, 1 / 30)
    m = measured["target"]
    assert not m.visible, (m.state, m.reason)
    if m.usable:  # fitted: then on the true corners
        err = np.abs(
            match_order(m.corners_px, target.corners_px) - order_corners(target.corners_px)
        )
        assert err.max() < 0.5, f"fitted corners off by {err.max():.2f} px"


def test_a_red_rectangle_of_another_size_is_not_the_target() -> None:
    hand, _ = scene()
    wide = Marker(square_3d(np.array([0.06, 0.04, 0.5]), SIZE_M, rotation(0.3, 0.8, 0.4)), RED)
    wide.points_m[1:3] += (wide.points_m[1] - wide.points_m[0]) * 0.5  # 9 cm by 6 cm
    rgb, depth = render([hand, wide])
    measured, _ = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, TrackerState(), 0.0)
    assert not measured["target"].visible, measured["target"].reason


def test_a_partly_hidden_target_is_fitted_from_a_coarser_depth_image_with_dropout() -> None:
    """Depth at half the colour resolution, with no depth (a Kinect's dropout, widened by its
    lateral noise) for 3-4 depth pixels either side of the hand's edge: that band spans twice
    as many colour pixels, and all of it must still be taken as the hand's (else the hand's
    edge is fitted as the target's, and the fit fails)."""
    k_small = CameraIntrinsics.from_fov(SHAPE[1] // 2, SHAPE[0] // 2, 57.0)

    def small(depth: np.ndarray) -> DepthImage:  # each small pixel's centre (2u + ½, 2v + ½)
        return DepthImage(np.ascontiguousarray(depth[1::2, 1::2]), k_small, 0.0)

    hand, target = scene()
    rgb, depth = render([hand, target])
    _, state = observe(rgb, K, small(depth), CFG, SIZE_M, TrackerState())
    assert "target" in state.memory
    box = box_over(target.corners_px, 0.4)
    cover(rgb, depth, box, 0.40)
    coarse = small(depth)
    edge = box[2] // 2  # the hand's left edge, in depth pixels
    coarse.depth_m[:, edge - 3 : edge + 4] = 0.0
    measured, _ = observe(rgb, K, coarse, CFG, SIZE_M, state, 1 / 30)
    m = measured["target"]
    assert m.state == "partial" and m.fitted and m.usable and m.occluded, m.reason
    err = np.abs(match_order(m.corners_px, target.corners_px) - order_corners(target.corners_px))
    assert err.max() < 0.5, f"fitted corners off by {err.max():.2f} px"


def test_a_target_slid_partly_out_of_the_picture_is_fitted_and_not_occluded() -> None:
    """Nothing is in front of it: the fit comes from the edges inside the image, and the
    blob's own occlusion check (run after the fit, whose occluder map is empty) says clear."""
    hand, _ = scene()
    rot = rotation(0.3, 0.8, 0.4)
    start_m = np.array([0.22, 0.04, 0.5])
    rgb, depth = render([hand, Marker(square_3d(start_m, SIZE_M, rot), RED)])
    _, state = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, TrackerState())
    target = Marker(square_3d(start_m + 0.03 * rot[:, 0], SIZE_M, rot), RED)  # slid in its plane
    assert target.corners_px[:, 0].max() > SHAPE[1] + 20  # a good part of it out of the image
    rgb, depth = render([hand, target])
    measured, _ = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, state, 1 / 30)
    m = measured["target"]
    assert (m.state, m.reason) == ("partial", "touches image border")
    assert m.fitted and m.usable and not m.occluded
    err = np.abs(match_order(m.corners_px, target.corners_px) - order_corners(target.corners_px))
    assert err.max() < 0.3, f"fitted corners off by {err.max():.2f} px"


@pytest.mark.parametrize("params", [(0.004, -0.003, 0.2), (0.01, 0.01, 0.7), (0.0, 0.0, -0.5)])
def test_the_fit_jacobian_matches_finite_differences(params: tuple[float, float, float]) -> None:
    """The partial fit's Jacobian is written out (partial._sides): d(distance)/d(params) of
    a pixel must match central differences of the distances themselves, for every side."""
    _, target = scene()
    square = partial.SquareOnPlane.from_corners(target.points_m, SIZE_M)
    pixels = np.column_stack([np.random.default_rng(3).uniform(150, 450, (20, 2)), np.ones(20)])

    def distances(p: np.ndarray) -> np.ndarray:
        return pixels @ partial._sides(*partial._corners_and_jacobian(square, p, K)).distance

    sides = partial._sides(*partial._corners_and_jacobian(square, np.array(params), K))
    analytic = (pixels @ sides.d_distance).reshape(-1, 4, 3)
    for j, step in enumerate((1e-6, 1e-6, 1e-5)):
        bump = np.eye(3)[j] * step
        numeric = (distances(np.add(params, bump)) - distances(np.subtract(params, bump))) / (
            2 * step
        )
        assert np.allclose(analytic[:, :, j], numeric, rtol=1e-6, atol=1e-7 * np.abs(numeric).max())
    # and the corners are those of the moved square
    moved = square.moved(*params).corners_m()
    assert np.allclose(sides.corners_px, project(moved, K))


def test_a_sliver_is_not_fitted_but_known_to_be_hidden() -> None:
    state, hand, target = first_view()
    rgb, depth = render([hand, target])
    cover(rgb, depth, box_over(target.corners_px, 0.93), 0.40)
    measured, _ = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, state, 1 / 30)
    m = measured["target"]
    assert not m.usable and not m.fitted and m.occluded, (m.state, m.reason)


@pytest.mark.parametrize(
    "case, occluded",
    [
        ("covered whole", True),  # the hand over it: hidden
        ("taken away", False),  # its place shows the surface it lay on, without its colour
        ("taken away, partly covered", False),  # the uncovered part still shows no red
        ("slid away under the hand", True),  # its place is now farther: the object moved
    ],
)
def test_hidden_is_told_from_gone(case: str, occluded: bool) -> None:
    state, hand, target = first_view()
    rgb, depth = frame_without_target(case, hand, target)
    measured, _ = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, state, 1 / 30)
    m = measured["target"]
    assert m.state == "lost" and m.occluded == occluded, (case, m.reason)


@pytest.mark.parametrize("case", ["covered whole", "taken away"])
def test_a_restarted_vision_cannot_tell_hidden_from_gone(case: str) -> None:
    """Not seen since vision started (a restart: its tracker is new), a lost target has no
    last view to look in front of: hidden or gone, ``occluded`` is None, not False."""
    _, hand, target = first_view()
    rgb, depth = frame_without_target(case, hand, target)
    measured, _ = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, TrackerState(), 1 / 30)
    m = measured["target"]
    assert m.state == "lost" and m.occluded is None, (case, m.reason)
    assert measured["hand"].visible and measured["hand"].occluded is False


def frame_without_target(case: str, hand: Marker, target: Marker) -> tuple[np.ndarray, np.ndarray]:
    """A frame with the hand and without the red square: ``case`` says why it is not seen."""
    rgb, depth = render([hand])  # no red square in this frame
    inside = polygon_mask(target.corners_px)
    surface = fit_inverse_depth_plane(
        pixel_to_normalized(np.argwhere(inside)[:, ::-1].astype(float), K),
        _plane_depths(target)[inside],
    )
    assert surface is not None
    if case != "slid away under the hand":  # the block under the marker stays
        rgb[inside] = (115, 140, 178)  # blue-grey block top
        depth[inside] = _plane_depths(target)[inside] + 1e-4
    if case == "covered whole":
        cover(rgb, depth, box_over(target.corners_px, 1.2), 0.40)
    elif case != "taken away":
        cover(rgb, depth, box_over(target.corners_px, 0.5), 0.40)
    return rgb, depth


def _plane_depths(marker: Marker) -> np.ndarray:
    return plane_depth_m(marker.points_m)


def test_between_depth_images_target_keeps_its_plane_and_hand_its_depths() -> None:
    state, hand, target = first_view()
    along = target.points_m[1] - target.points_m[0]
    slide = 0.01 * along / np.linalg.norm(along)  # 1 cm along the table top (its plane)
    moved_target = Marker(target.points_m + slide, RED)
    rgb, depth = render([hand, moved_target])
    measured, _ = observe(rgb, K, DepthImage(depth, K, 0.5), CFG, SIZE_M, state, 0.5)
    t, h = measured["target"], measured["hand"]
    assert t.visible and h.visible
    order = [
        int(np.argmin(np.linalg.norm(moved_target.corners_px - c, axis=1))) for c in t.corners_px
    ]
    np.testing.assert_allclose(t.depth_m, moved_target.points_m[order, 2], atol=2e-3)
    np.testing.assert_array_equal(h.depth_m, state.memory["hand"].depth_m)  # held as measured


def test_a_cut_target_between_depth_images_is_refused_by_its_size() -> None:
    """Without a fresh depth image a square cut along a side by something in front still
    looks like a quadrilateral; on the remembered plane its sides come out short."""
    state, hand, target = first_view()
    rgb, depth = render([hand, target])
    u_mid = int(target.corners_px[:, 0].mean())
    rgb[:, u_mid:] = np.where(
        polygon_mask(target.corners_px)[:, u_mid:, None], SKIN, rgb[:, u_mid:]
    )
    measured, _ = observe(rgb, K, DepthImage(depth, K, 0.5), CFG, SIZE_M, state, 0.5)
    assert not measured["target"].visible
    assert measured["target"].reason in {"not the marker's size", "not a quadrilateral"}


def test_no_depth_when_the_depth_image_is_too_old() -> None:
    state, hand, target = first_view()
    rgb, depth = render([hand, target])
    old = DepthImage(depth, K, CFG.max_depth_age_s + 0.1)
    measured, _ = observe(rgb, K, old, CFG, SIZE_M, state, 2.0)
    assert all(
        m.state == "no_depth" and m.reason == "depth image too old" for m in measured.values()
    )
    measured, _ = observe(rgb, K, None, CFG, SIZE_M, TrackerState(), 0.0)
    assert all(m.state == "no_depth" and m.reason == "no depth image" for m in measured.values())


def test_depth_at_a_lower_resolution_is_registered_to_colour() -> None:
    hand, target = scene()
    rgb, _ = render([hand, target])
    k_small = CameraIntrinsics.from_fov(320, 240, 57.0)
    v, u = np.mgrid[0:240, 0:320].astype(float)
    rays = np.column_stack(
        [pixel_to_normalized(np.column_stack([u.ravel(), v.ravel()]), k_small), np.ones(u.size)]
    )
    depth = np.full(u.size, 1.6, np.float32)
    for m in (hand, target):  # each square's plane where its (small) pixels see it
        n = np.cross(m.points_m[1] - m.points_m[0], m.points_m[3] - m.points_m[0])
        z = n @ m.points_m[0] / (rays @ n)
        small = (m.corners_px + 0.5) / 2.0 - 0.5
        depth = np.where(polygon_mask(small, (240, 320)).ravel(), z, depth)
    measured = measure_markers(
        rgb, depth.reshape(240, 320).astype(np.float32), K, CFG, k_depth=k_small
    )
    for name, marker in (("hand", hand), ("target", target)):
        m = measured[name]
        assert m.visible, m.reason
        order = [
            int(np.argmin(np.linalg.norm(marker.corners_px - c, axis=1))) for c in m.corners_px
        ]
        np.testing.assert_allclose(m.depth_m, marker.points_m[order, 2], atol=1e-3)


@pytest.mark.parametrize("depth_shape", [(240, 320), (160, 213), (120, 160)])
def test_a_registered_crop_is_that_crop_of_the_registered_mask(
    depth_shape: tuple[int, int],
) -> None:
    """Vision registers only a marker's box of its mask to the depth image: the same pixels as
    the whole mask registered, whether the sizes are whole multiples (resampled by blocks)
    or not (the whole mask resampled)."""
    rng = np.random.default_rng(3)
    blobs = (rng.random((48, 64)) < 0.5).astype(np.uint8) * 255
    mask = np.kron(blobs, np.ones((10, 10), np.uint8))  # 480×640, blocks off the depth grid
    mask[rng.random(mask.shape) < 0.05] ^= 255
    whole = registered_mask(mask, depth_shape)
    assert 0 < np.count_nonzero(whole) < whole.size and set(np.unique(whole)) == {0, 255}
    for _ in range(20):
        r0, c0 = rng.integers(0, depth_shape[0] - 2), rng.integers(0, depth_shape[1] - 2)
        r1, c1 = rng.integers(r0 + 1, depth_shape[0] + 1), rng.integers(c0 + 1, depth_shape[1] + 1)
        crop = registered_mask(mask, depth_shape, (r0, r1, c0, c1))
        assert np.array_equal(crop, whole[r0:r1, c0:c1])


def test_occlusion_is_seen_past_the_invalid_band_along_an_occluder() -> None:
    """A Kinect leaves no depth along an occluder's edge, exactly where it borders the marker:
    those invalid pixels next to a closer surface count; a closer object that does not touch
    the marker does not."""
    mask = np.zeros((100, 100), np.uint8)
    mask[30:70, 30:70] = 255
    depth = np.full((100, 100), 0.5, np.float32)
    touching = depth.copy()
    touching[:, 70:] = 0.4  # an occluder right at the marker's right side...
    touching[:, 70:74] = 0.0  # ... whose edge is invalid for 4 px
    assert occluder_fraction(touching, mask, 0.5, reach_px=5) > 0.1
    assert occluder_fraction(touching, mask, 0.5, reach_px=1) < 0.03  # reach too short: missed
    apart = depth.copy()
    apart[:, 76:] = 0.4  # 6 px away, its edge invalid too: valid background between
    apart[:, 76:79] = 0.0
    assert occluder_fraction(apart, mask, 0.5, reach_px=5) == 0.0


def test_hidden_behind_reads_depth_and_colour() -> None:
    region = np.zeros((20, 20), np.uint8)
    region[5:15, 5:15] = 255
    surface = np.full((20, 20), 0.5)
    red = np.zeros((20, 20), np.uint8)
    depth = np.full((20, 20), 0.5, np.float32)
    assert not hidden_behind(depth, region, surface, red)  # nothing in front
    depth[5:15, 5:10] = 0.45  # half covered, the other half not red: gone
    assert not hidden_behind(depth, region, surface, red)
    red[5:15, 10:15] = 255  # ... the other half red: partly hidden
    assert hidden_behind(depth, region, surface, red)
    depth[5:15, 10:15] = 0.6  # ... the other half now farther: it slid away, hidden
    assert hidden_behind(depth, region, surface, np.zeros_like(red))


def test_corner_depth_uncertainty_is_calibrated_on_noisy_planes() -> None:
    """Depth with Kinect-like axial noise (σ 1.2 mm at 0.5 m): about 95 % of the corner depth
    errors within twice the reported 1-σ."""
    rng = np.random.default_rng(5)
    within, total = 0, 0
    for _ in range(40):
        tilt = rotation(rng.uniform(-0.6, 0.6), rng.uniform(0.3, 0.9), rng.uniform(-3, 3))
        centre = np.array(
            [rng.uniform(-0.1, 0.1), rng.uniform(-0.08, 0.08), rng.uniform(0.45, 0.6)]
        )
        marker = Marker(square_3d(centre, SIZE_M, tilt), RED)
        rgb, depth = render([marker])
        noise = rng.normal(0.0, 1.0, SHAPE) * (0.0012 + 0.0019 * (depth - 0.4) ** 2)
        m = measure_markers(rgb, (depth + noise).astype(np.float32), K, CFG)["target"]
        assert m.visible
        order = [
            int(np.argmin(np.linalg.norm(marker.corners_px - c, axis=1))) for c in m.corners_px
        ]
        err = np.abs(m.depth_m - marker.points_m[order, 2])
        within += int(np.count_nonzero(err <= 2.0 * m.depth_sigma_m))
        total += 4
    coverage = within / total
    print(f"corner depths within 2 reported sigma: {coverage:.1%} of {total}")
    assert 0.88 <= coverage <= 0.995


def test_a_hand_view_older_than_a_depth_image_may_be_is_not_held() -> None:
    """The hand approaches, stops, and from then on its depth is invalid in every depth image
    (nearer than the sensor's range): between the images its last view with depth, carried
    along its motion, went on drifting towards the camera, below zero within seconds (and
    ended vision). No older than ``max_depth_age_s``, as a depth image, then no depth."""
    hand, target = scene()

    def frame(t: float) -> tuple[np.ndarray, np.ndarray, Marker]:
        moved = Marker(hand.points_m + np.array([0.0, 0.0, -0.1 * min(t, 0.5)]), hand.colour)
        rgb, depth = render([moved, target])
        return rgb, depth, moved

    state = TrackerState()
    for t in np.arange(0.0, 0.5001, 0.1):  # seen with depth while it moves: its velocity
        rgb, depth, _ = frame(t)
        _, state = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, state, t)
    held = []
    for t in np.arange(1.0, 5.01, 0.5):  # depth at 1 Hz from now on, none valid on the hand
        rgb, depth, moved = frame(t)
        depth[polygon_mask(moved.corners_px)] = 0.0
        age = 0.0 if t == round(t) else 0.5
        markers, state = observe(rgb, K, DepthImage(depth, K, age), CFG, SIZE_M, state, t)
        hand_now = markers["hand"]
        if hand_now.usable:
            assert np.all(hand_now.depth_m > 0.2), (t, hand_now.depth_m)
            hand_now.to_wire()  # a message the controller can act on
        held.append((t, hand_now.state, hand_now.reason))
    assert held[1] == (1.5, "visible", "")  # within a depth image's age of its view: held
    assert all(r[1:] == ("no_depth", "depth of it too old") for r in held[3::2])  # 2.5 s on


def test_a_target_gone_from_its_window_is_looked_for_in_the_whole_image() -> None:
    """The target moved away, a small red patch left where it was: its last visible corners
    kept the search in a window around the patch for ever ("not the marker's size" every
    frame) while the target lay whole elsewhere. The window is for a marker seen whole in the
    frame before, so after one frame of it the whole image is searched."""
    hand, target = scene()
    rgb, depth = render([hand, target])
    _, state = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, TrackerState(), 0.0)
    moved = Marker(square_3d(np.array([0.06, -0.10, 0.5]), SIZE_M, rotation(0.3, 0.8, 0.4)), RED)
    rgb, depth = render([hand, moved])
    u, v = target.corners_px.mean(axis=0).astype(int)
    rgb[v - 5 : v + 5, u - 5 : u + 5] = RED
    states = []
    for t in (0.1, 0.2, 0.3):
        markers, state = observe(rgb, K, fresh(rgb, depth), CFG, SIZE_M, state, t)
        states.append(markers["target"].state)
    assert states == ["partial", "visible", "visible"]
