"""Static scenery cut to what the camera sees (services.sim.scenery): the cut keeps every face
towards the camera, inside the view, wound for the renderer, and renders the same images."""

from __future__ import annotations

import numpy as np

from common.camera import CameraIntrinsics
from common.config import load_scenario
from common.runtime import parse_overrides
from services.sim.scenery import view_frustum, visible_box
from services.sim.urdf import TORSO_CENTRE_M, TORSO_SIZE_M
from services.sim.world import World

K = CameraIntrinsics(width_px=320, height_px=240, fx_px=300.0, fy_px=300.0, cx_px=160, cy_px=120)
LOOKING_ALONG_Z = np.eye(4)  # optical frame = base frame: the camera at the origin looks along +z
NEAR_M = 0.05


def inside(point: np.ndarray, frustum: list) -> bool:
    return all(float(n @ point) >= offset - 1e-9 for n, offset in frustum)


def test_a_box_in_full_view_keeps_only_its_face_towards_the_camera_uncut() -> None:
    frustum = view_frustum(LOOKING_ALONG_Z, K, NEAR_M)
    mesh = visible_box((0.1, 0.1, 0.1), np.array([0.0, 0.0, 2.0]), np.zeros(3), frustum)
    assert mesh is not None
    # Straight ahead, only the near face (z = 1.9) turns towards the camera.
    expected = [(x, y, -0.1) for x in (-0.1, 0.1) for y in (-0.1, 0.1)]
    np.testing.assert_allclose(sorted(map(tuple, mesh.vertices)), expected, atol=1e-12)
    assert mesh.normals == [[0.0, 0.0, -1.0]] * 4
    assert len(mesh.indices) == 6


def test_a_floor_under_and_behind_the_camera_is_cut_to_the_view() -> None:
    camera = np.eye(4)
    down = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])  # optical z along -y (y is up)
    camera[:3, :3] = down @ [[1, 0, 0], [0, 0.8, -0.6], [0, 0.6, 0.8]]  # tilted by 37°
    camera[:3, 3] = [0.0, 1.0, 0.0]
    frustum = view_frustum(camera, K, NEAR_M)
    centre = np.array([0.0, -0.01, 0.0])
    mesh = visible_box((5.0, 0.01, 5.0), centre, camera[:3, 3], frustum)
    assert mesh is not None
    vertices = np.array(mesh.vertices) + centre
    assert all(inside(v, frustum) for v in vertices)
    assert np.ptp(vertices[:, 0]) < 10.0  # cut: the floor is 10 m wide
    assert mesh.normals == [[0.0, 1.0, 0.0]] * len(mesh.vertices)  # its top face alone
    for a, b, c in np.reshape(mesh.indices, (-1, 3)):  # counter-clockwise seen from above
        assert np.cross(vertices[b] - vertices[a], vertices[c] - vertices[a])[1] > 0


def test_a_box_behind_the_camera_gives_nothing_to_draw() -> None:
    frustum = view_frustum(LOOKING_ALONG_Z, K, NEAR_M)
    assert visible_box((0.1, 0.1, 0.1), np.array([0.0, 0.0, -1.0]), np.zeros(3), frustum) is None
    # Beside the view (60° off the axis, the half field of view is 28°): nothing either.
    assert visible_box((0.1, 0.1, 0.1), np.array([1.7, 0.0, 1.0]), np.zeros(3), frustum) is None


def test_cut_scenery_renders_the_images_of_whole_boxes_and_the_torso_where_it_is() -> None:
    size = ["camera.width_px=320", "camera.height_px=240", "sim.renderer='tiny'"]
    scenario = load_scenario(None, parse_overrides(size))  # the cut serves TinyRenderer alone
    images = {}
    for clip in (True, False):
        world = World(scenario, clip_scenery=clip)
        try:
            images[clip] = world.render()
        finally:
            world.close()
    (rgb_cut, depth_cut), (rgb_whole, depth_whole) = images[True], images[False]
    np.testing.assert_array_equal(rgb_cut, rgb_whole)
    np.testing.assert_allclose(depth_cut, depth_whole, rtol=0, atol=1e-5)  # float rounding
    # The image's bottom right corner sees the torso's front face: depth = the ray's hit on it.
    k, pose = scenario.camera.intrinsics(), scenario.camera.pose()
    u, v = k.width_px - 1, k.height_px - 1
    ray = pose[:3, :3] @ np.array([(u - k.cx_px) / k.fx_px, (v - k.cy_px) / k.fy_px, 1.0])
    front_x_m = TORSO_CENTRE_M[0] + TORSO_SIZE_M[0] / 2
    z_cam_m = (front_x_m - pose[0, 3]) / ray[0]  # ray has unit optical-axis component
    assert 0.05 < z_cam_m < 1.0
    assert abs(float(depth_cut[v, u]) - z_cam_m) < 1e-3
