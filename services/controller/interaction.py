"""Interaction matrices and each strategy's control matrix (ViSP's features and their builders).

Sign convention (Chaumette & Hutchinson, Part II). The classic point interaction matrix ``L``
relates feature motion to the twist of a *moving camera*. Here the camera is fixed and the
points ride on the hand: a hand twist ``(v, ω)`` expressed in the camera frame and referenced at
the camera origin moves a point by ``Ṗ = v + ω × P``, which is the opposite of a camera moving
with ``(v, ω)``. Hence ``ṡ = -L · (v, ω)`` and imposing ``ė = -λ e`` gives ``(v, ω) = +λ L⁺ e``.
The four strategies of the thesis only differ in the matrix that replaces ``L⁺``.

A fifth strategy, ``points3d``, uses the depth camera further: its features are the hand
marker's four corners as 3-D points in the camera frame (``e = P - P*``, 12 entries, metres).
Its Jacobian comes straight from ``Ṗ = v + ω × P = [I₃  -[P]×] · (v, ω)`` with no minus sign,
so ``ė = J · (v, ω)`` (P* is fixed) and ``ė = -λ e`` gives ``(v, ω) = -λ J⁺ e``: the opposite
sign to the image points. Every corner is driven along its own straight line to its goal, so
the hand follows a nearly straight 3-D path and converges in depth, not only in the image.
Every law is written ``(v, ω) = λ · M · e``; only ``M`` and ``e`` differ. Pure functions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from common.camera import CameraIntrinsics, pixel_to_normalized
from common.config import ConstantDepth, JacobianMode
from common.kinematics import pinv, skew
from common.marker import Marker

FloatArray = NDArray[np.float64]


def interaction_matrix(xy: FloatArray, depth_m: FloatArray) -> FloatArray:
    """Stacked 2N×6 point interaction matrix at normalized points ``xy`` (N×2), depths Z (N,).

    Row pair per point (thesis eq. 5.30):
    ``[-1/Z, 0, x/Z, x·y, -(1+x²), y]`` and ``[0, -1/Z, y/Z, 1+y², -x·y, -x]``.
    """
    x, y = xy[:, 0], xy[:, 1]
    inv_z = 1.0 / np.asarray(depth_m, dtype=float)
    out = np.zeros((2 * len(x), 6))
    rows_u, rows_v = out[0::2], out[1::2]  # views: filled column by column
    rows_u[:, 0], rows_u[:, 2], rows_u[:, 3] = -inv_z, x * inv_z, x * y
    rows_u[:, 4], rows_u[:, 5] = -(1.0 + x * x), y
    rows_v[:, 1], rows_v[:, 2], rows_v[:, 3] = -inv_z, y * inv_z, 1.0 + y * y
    rows_v[:, 4], rows_v[:, 5] = -x * y, -x
    return out


def point_feature_jacobian(points_m: FloatArray) -> FloatArray:
    """Stacked 3N×6 Jacobian of 3-D points ``points_m`` (N×3, camera frame) riding on the hand.

    For a hand twist ``(v, ω)`` in the camera frame referenced at the camera origin each point
    moves by ``Ṗ = v + ω × P = v - [P]× ω``, hence the block ``[I₃  -[P]×]`` per point. Three
    non-collinear points already give rank 6 (only a zero twist leaves them all still).
    """
    points = np.asarray(points_m, dtype=float)
    out = np.empty((3 * len(points), 6))
    for i, p in enumerate(points):
        out[3 * i : 3 * i + 3, :3] = np.eye(3)
        out[3 * i : 3 * i + 3, 3:] = -skew(p)
    return out


def points3d_control_matrix(points_m: FloatArray) -> FloatArray:
    """The 6×3N matrix ``M = -J⁺`` of ``(v, ω) = λ · M · e`` for ``e = P - P*``.

    ``J`` is :func:`point_feature_jacobian` at the current (measured) points: the minus sign is
    that of ``ė = J · (v, ω) = -λ e``, not the ``+`` of the image points (see the module doc).
    """
    return -pinv(point_feature_jacobian(points_m))


# The interaction matrices each image-point strategy is built from (the others are not needed).
USES_CURRENT = frozenset({JacobianMode.DYNAMIC, JacobianMode.PMJ, JacobianMode.MPJ})


USES_DESIRED = frozenset({JacobianMode.PMJ, JacobianMode.MPJ})


def control_matrix(
    mode: JacobianMode,
    l_current: FloatArray | None,
    l_desired: FloatArray | None,
    l_constant: FloatArray | None,
) -> FloatArray:
    """The 6×2N matrix ``M`` of ``(v, ω) = λ · M · e`` for each image-point strategy.

    - constant: ``L_c⁺`` (frozen at the desired features with one depth taken at the start);
    - dynamic:  ``L_n⁺`` (current features, current per-point depths);
    - pmj:      ``((L_n + L*)/2)⁺``  (Malis: pseudo-inverse of the mean);
    - mpj:      ``(L_n⁺ + L*⁺)/2``   (mean of the pseudo-inverses).

    A matrix the mode does not use may be None (:data:`USES_CURRENT`, :data:`USES_DESIRED`).
    points3d does not use image points: its matrix is :func:`points3d_control_matrix`.
    """

    def given(matrix: FloatArray | None, name: str) -> FloatArray:
        if matrix is None:
            raise ValueError(f"{mode.value} needs {name}")
        return matrix

    if mode is JacobianMode.CONSTANT:
        return pinv(given(l_constant, "l_constant"))
    if mode is JacobianMode.DYNAMIC:
        return pinv(given(l_current, "l_current"))
    if mode is JacobianMode.PMJ:
        return pinv(0.5 * (given(l_current, "l_current") + given(l_desired, "l_desired")))
    if mode is JacobianMode.MPJ:
        pinv_current = pinv(given(l_current, "l_current"))
        return 0.5 * (pinv_current + pinv(given(l_desired, "l_desired")))
    if mode is JacobianMode.POINTS3D:
        raise ValueError("points3d servoes 3-D points: use points3d_control_matrix")
    raise ValueError(f"unknown Jacobian mode {mode!r}")


def constant_interaction_matrix(
    desired: Marker, k: CameraIntrinsics, depth: ConstantDepth
) -> FloatArray:
    """The constant strategy's matrix, built once at the start at the desired features: with
    one depth for all corners, the desired corners' mean (the thesis), or with each corner's
    own (``per_corner``). One depth treats the target's square as facing the camera; seen
    obliquely from the torso, its corners' depths differ by centimetres, and from some starts
    the law then settles where ``L_c⁺ e = 0`` with ``e ≠ 0`` (docs/campaign.md)."""
    xy = pixel_to_normalized(desired.corners_px, k)
    depths = np.asarray(desired.depth_m, dtype=float)
    if depth is ConstantDepth.SINGLE:
        depths = np.full(len(xy), float(np.mean(depths)))
    return interaction_matrix(xy, depths)


def image_feature_rate(xy: FloatArray, depth_m: FloatArray, velocity_m_s: FloatArray) -> FloatArray:
    """ṡ (2N,) of normalized points at ``xy`` (N×2), depths Z (N,), all translating with
    ``velocity_m_s`` in the camera frame: ẋ = (vx − x·vz)/Z, ẏ = (vy − y·vz)/Z."""
    vx, vy, vz = velocity_m_s
    rates = np.empty((len(xy), 2))
    rates[:, 0] = (vx - xy[:, 0] * vz) / depth_m
    rates[:, 1] = (vy - xy[:, 1] * vz) / depth_m
    return rates.reshape(-1)
