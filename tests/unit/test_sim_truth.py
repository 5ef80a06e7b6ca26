"""The simulator's ground truth of the markers' image corners, for judging a run: defined for
any posture, also one that puts a marker far out of view or behind the camera."""

from __future__ import annotations

import numpy as np

from common.camera import CameraIntrinsics, project
from common.messages import PIXEL_LIMIT_PX, Header
from services.sim.truth import Truth, square_pixels, truth_corners_px, truth_message

K = CameraIntrinsics.from_fov(640, 480, 57.0)


def test_corners_in_view_are_their_projection() -> None:
    corners = np.array([[0.01, 0.02, 0.5], [0.07, 0.02, 0.5], [0.07, 0.08, 0.52], [0.0, 0.1, 0.6]])
    assert np.array_equal(truth_corners_px(corners, K), project(corners, K))


def test_corners_far_out_of_view_or_behind_the_camera_lie_beyond_the_image_on_their_side() -> None:
    corners = np.array([
        [3.0, 0.0, 0.01],  # far to the right, nearly in the camera's plane
        [0.2, 0.0, -0.3],  # behind the camera, to the right: not mirrored into the image
        [-0.2, 0.1, 0.0],  # in the camera's plane, to the left
        [0.0, -5.0, 0.2],  # far above
    ])  # fmt: skip
    uv = truth_corners_px(corners, K)
    assert np.all(np.abs(uv) <= PIXEL_LIMIT_PX)
    assert uv[0, 0] == PIXEL_LIMIT_PX and uv[1, 0] == PIXEL_LIMIT_PX
    assert uv[2, 0] == -PIXEL_LIMIT_PX and uv[3, 1] == -PIXEL_LIMIT_PX
    pose = np.eye(4).reshape(-1)
    truth = Truth(pose.reshape(4, 4), pose.reshape(4, 4), uv, uv, np.zeros(3))
    header = Header(seq=0, sim_time_s=0.0, send_time_s=0.0, frame_seq=0)
    message = truth_message(truth, header, np.zeros(6))  # valid on the wire: no ValidationError
    assert message.hand_corners_px[0][0] == PIXEL_LIMIT_PX


def test_a_quad_far_larger_than_the_image_is_measured_not_drawn() -> None:
    """Its pixels in the image, and its whole area, without drawing a 2·10⁴-pixel box."""
    big = np.array([[-9000.0, -9000.0], [9000.0, -9000.0], [9000.0, 9000.0], [-9000.0, 9000.0]])
    inside, total = square_pixels(big, 0.0, (480, 640))
    assert inside.shape == (480, 640) and inside.all()
    assert abs(total - 18000.0**2) < 1e-3 * 18000.0**2
    small = np.array([[100.0, 100.0], [140.0, 100.0], [140.0, 140.0], [100.0, 140.0]])
    inside, total = square_pixels(small, 0.0, (480, 640))
    assert total == np.count_nonzero(inside) and 1500 < total < 1800
