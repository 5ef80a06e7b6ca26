"""Keep the hand above the top face of the object it reaches for. Pure.

The goal puts the hand marker ``approach_height_m`` above the red one, which leaves the
hand's box (under its marker) a few millimetres above the object's top face. On the way the
image law turns the hand freely, and a turn about a horizontal axis dips one edge of the box
by centimetres: the hand struck the object from starts beside it, the contact drove a wrist
joint past its limit and the run never recovered.

The top face's plane comes from vision (the red marker's measured corners, through the
assumed camera pose); the hand box's corners from the encoders (forward kinematics and the
robot model). Each corner's height ``h`` above the plane may fall no faster than
``rate · (h − h_min)`` (a control barrier: it slows to a stop at ``h_min``): with ``n`` the
plane's upward normal and ``d`` the corner from the end-effector origin,
``ḣ = n · v + (d × n) · ω``, one linear bound per corner (:func:`clearance_bounds`). A twist
that breaks one is changed where the image law's features notice it least
(:func:`.constrained.least_feature_change`), and whatever that leaves short is made up by the
least upward velocity ``δ n`` (:func:`lift_short`, also the whole correction of a twist the
law did not make, such as acquisition's); a bound rising does not help (the forearm's, beside
the object) is then met by the nearest twist that does (:func:`lift_then_nearest`). The hand
box keeps the whole plane, beyond the object's sides too: the starts lie above their goal, the
goal above the plane. The forearm,
which at the goal lies below the plane beside the object, is kept off the object itself
(:mod:`.forearm`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from common import kinematics as kin
from services.controller.constrained import least_feature_change

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Plane:
    """A point on the plane and its unit normal, base frame (m)."""

    point_m: FloatArray
    normal: FloatArray


@functools.cache
def hand_box_corners_ee() -> FloatArray:
    """The hand box's eight corners in DH frame 6 (8×3, m; the sim's URDF builds the box from
    the same dimensions); made once, read-only."""
    centre = np.array([0.0, kin.HAND_OFFSET_M + kin.HAND_LENGTH_M / 2, 0.0])
    half = np.array([kin.HAND_THICKNESS_M, kin.HAND_LENGTH_M, kin.HAND_WIDTH_M]) / 2
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    corners = centre + signs * half
    corners.setflags(write=False)
    return corners


# A square's first edge (and the product of its first two) is half of what its diagonals give
# (see plane_of_corners): under this share of it the edges are taken as degenerate.
DEGENERATE_SHARE = 0.1


def plane_of_corners(points: FloatArray, origin: FloatArray) -> Plane:
    """The plane of the red marker's four corners (base frame, m), its normal turned towards
    the camera's optical centre ``origin`` (up, out of the object)."""
    centre = kin.centroid(points)
    normal = kin.cross(points[1] - points[0], points[3] - points[0])
    diagonals = kin.cross(points[2] - points[0], points[3] - points[1])
    # A square's edge product is half its diagonals'; far less, corners 0, 1, 3 are (nearly)
    # in a line or merged, and the diagonals, which the wire checks, do cross.
    if kin.norm(normal) < DEGENERATE_SHARE * kin.norm(diagonals):
        normal = diagonals
    normal = normal / kin.norm(normal)
    if normal @ (origin - centre) < 0:
        normal = -normal
    return Plane(centre, normal)


def heights_m(corners_base_m: FloatArray, plane: Plane) -> FloatArray:
    """Each corner's signed height above the plane (m)."""
    return (np.asarray(corners_base_m, dtype=float) - plane.point_m) @ plane.normal


def clearance_bounds(
    corners_base_m: FloatArray,
    p_ee_base_m: FloatArray,
    plane: Plane,
    min_height_m: float,
    rate_1_s: float,
) -> tuple[FloatArray, FloatArray]:
    """``(A, b)``, every corner's bound as ``A · twist ≥ b`` (8×6, 8): ``A`` gives each
    corner's ``ḣ`` for a twist (v, ω at the end-effector origin, base frame), ``b`` the least
    ``ḣ`` allowed, ``−rate · (h − h_min)`` (positive: a corner below the margin must rise)."""
    corners = np.asarray(corners_base_m, dtype=float)
    n = plane.normal
    lever = corners - p_ee_base_m
    rows = np.empty((len(corners), 6))
    rows[:, :3] = n
    rows[:, 3], rows[:, 4], rows[:, 5] = kin.cross_components(lever, n)  # lever × n, each corner
    return rows, -rate_1_s * (heights_m(corners, plane) - min_height_m)


def lift_short(
    twist: FloatArray, rows: FloatArray, bounds: FloatArray, normal: FloatArray
) -> tuple[FloatArray, bool]:
    """``twist`` with the least upward velocity ``δ n`` that meets ``rows · twist ≥ bounds``,
    and whether it lifted it. An upward velocity raises every corner of the hand box at its
    own rate (:func:`clearance_bounds`: ``δ`` is then the largest shortfall); another bound
    (the forearm's, :mod:`.forearm`) gains ``rows · (n, 0)`` per unit of it, and one that
    rising does not help is left short (:func:`lift_then_nearest` meets it)."""
    short = bounds - rows @ twist
    if float(np.max(short, initial=0.0)) <= 0.0:
        return twist, False
    gain = rows[:, :3] @ normal  # each bound's rate per unit of upward velocity
    helped = (short > 0.0) & (gain > 1e-9)
    if not np.any(helped):
        return twist, False
    lifted = np.array(twist, dtype=float)
    lifted[:3] += float(np.max(short[helped] / gain[helped])) * normal
    return lifted, True


def lift_then_nearest(
    twist: FloatArray, rows: FloatArray, bounds: FloatArray, normal: FloatArray
) -> tuple[FloatArray, bool]:
    """``twist`` meeting ``rows · twist ≥ bounds``, and whether it broke one: lifted by the
    least upward velocity (:func:`lift_short`), then, where a bound is still short because
    rising does not help it, the nearest twist that meets them all (the least ``‖Δ‖``,
    :func:`.constrained.least_feature_change` with ``W = I``), lifted again by what its
    sweeps left short: the hand box's corners, which rising always helps, end met."""
    broke = bool((rows @ twist < bounds).any())
    lifted, _ = lift_short(twist, rows, bounds, normal)
    if (rows @ lifted >= bounds).all():
        return lifted, broke
    nearest, _ = least_feature_change(lifted, rows, bounds, np.eye(6))
    return lift_short(nearest, rows, bounds, normal)[0], broke
