"""The renderers' camera maths: pybullet's view and projection matrices for the torso camera's
optical frame and pinhole intrinsics, the light, and an OpenGL depth buffer in metres. Pure
functions of plain data; the world (:mod:`services.sim.world`) hands them to TinyRenderer."""

from __future__ import annotations

import numpy as np

from common.camera import CameraIntrinsics

FloatArray = np.ndarray


def opengl_view_matrix(t_base_cam: FloatArray) -> list[float]:
    """pybullet view matrix (column-major) for an optical-frame camera pose.

    OpenGL's camera looks down its -z with y up; the optical frame looks down +z with y down.
    """
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    view = flip @ np.linalg.inv(t_base_cam)
    return view.flatten(order="F").tolist()


# Where TinyRenderer samples pixel (row i, column j) in the frustum it is given, as the shift
# (du, dv) of the principal point that lines its pixels up with the pinhole model. Measured
# against projected truth: TinyRenderer samples (j - 0.5, i + 0.5).
TINY_PIXEL_SHIFT_PX = (0.0, 1.0)
LIGHT_DIRECTION = (0.4, -0.3, 1.0)  # towards the light, world frame (pybullet's convention)


def opengl_projection_matrix(k: CameraIntrinsics, near_m: float, far_m: float) -> list[float]:
    """Column-major OpenGL projection for TinyRenderer whose pixel centres match
    ``u = fx·x + cx`` exactly.

    The off-centre terms place the principal point so that rendered pixels line up with the
    pinhole model of :mod:`common.camera` (pixel centres at integer coordinates), for
    TinyRenderer's sampling (:data:`TINY_PIXEL_SHIFT_PX`).
    """
    w, h = k.width_px, k.height_px
    du, dv = TINY_PIXEL_SHIFT_PX
    p = np.zeros((4, 4))
    p[0, 0] = 2.0 * k.fx_px / w
    p[1, 1] = 2.0 * k.fy_px / h
    p[0, 2] = -(2.0 * (k.cx_px + du) / w - 1.0)  # image x right; OpenGL looks down -z
    p[1, 2] = 2.0 * (k.cy_px + dv) / h - 1.0  # image y down vs OpenGL y up
    p[2, 2] = -(far_m + near_m) / (far_m - near_m)
    p[2, 3] = -2.0 * far_m * near_m / (far_m - near_m)
    p[3, 2] = -1.0
    return p.flatten(order="F").tolist()


def depth_buffer_to_metres(buffer: FloatArray, near_m: float, far_m: float) -> FloatArray:
    """OpenGL depth buffer (0..1, non-linear) to Z along the optical axis (m), float32.

    Pixels at the far plane (nothing rendered) become 0, the "invalid" value of a Kinect.
    Computed in float32, the buffer's own type (far faster than through float64), within
    5e-5 m of the float64 result up to 5 m (1e-5 relative), far below a depth camera's
    millimetres.
    """
    b = np.asarray(buffer, dtype=np.float32)
    far, near = np.float32(far_m), np.float32(near_m)
    z = (far * near) / (far - (far - near) * b)
    z[b >= 1.0] = 0.0
    return z
