"""Static scenery as the renderer should get it: only what the camera can see. Pure functions.

TinyRenderer scans the screen box of every triangle it is given, clipped to the image, and
shades each pixel there that passes the depth test. A face that reaches outside the view
(the floor runs under and behind the camera; the torso's front face passes a centimetre
behind it) costs as if it covered the image, though little of it shows (the torso, a few
hundred pixels in a corner of the image, cost as much as a large part of the frame; see
docs/performance.md). They never move, and neither does the camera, so each
of their faces is cut once, at start, to the view frustum (grown by a margin, so that no
pixel is near a cut), and the faces turned away from the camera are dropped. The images are
those of the whole boxes: colour bit for bit, depth to a few micrometres (float rounding at
the new vertices). (As a link of the robot's URDF the torso lost that corner: the floor
showed through it. Drawn as a box of its own, cut or whole, its depth there is the ray's.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.camera import CameraIntrinsics

FloatArray = np.ndarray
HalfSpace = tuple[FloatArray, float]  # points p with normal·p >= offset

VIEW_MARGIN_FRACTION = 0.05  # the frustum is grown by this fraction of the image on each side
NEAR_FRACTION = 0.5  # cut at this fraction of the near plane's distance (nearer is not drawn)
_FACES = ((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0), (2, 1.0), (2, -1.0))  # axis, outward sign


@dataclass(frozen=True)
class Mesh:
    """Triangles for ``createVisualShape(GEOM_MESH, ...)``: each face's own vertices (flat
    normals), indices counter-clockwise seen from outside."""

    vertices: list[list[float]]
    indices: list[int]
    normals: list[list[float]]


def view_frustum(camera_pose: FloatArray, k: CameraIntrinsics, near_m: float) -> list[HalfSpace]:
    """The half-spaces (base frame) of what a camera at ``camera_pose`` (optical frame: z
    forward, y down) with intrinsics ``k`` can draw: beyond :data:`NEAR_FRACTION` of
    ``near_m``, and inside the rays through the image's corners grown by
    :data:`VIEW_MARGIN_FRACTION` (the same field of view at any resolution)."""
    eye, rot = camera_pose[:3, 3], camera_pose[:3, :3]
    m_u, m_v = VIEW_MARGIN_FRACTION * k.width_px, VIEW_MARGIN_FRACTION * k.height_px
    us, vs = (-m_u, k.width_px + m_u), (-m_v, k.height_px + m_v)
    corners = [(us[0], vs[0]), (us[1], vs[0]), (us[1], vs[1]), (us[0], vs[1])]
    rays = [
        rot @ np.array([(u - k.cx_px) / k.fx_px, (v - k.cy_px) / k.fy_px, 1.0]) for u, v in corners
    ]
    forward = rot[:, 2]
    planes: list[HalfSpace] = [(forward, float(forward @ eye) + NEAR_FRACTION * near_m)]
    for a, b in zip(rays, rays[1:] + rays[:1], strict=True):
        normal = np.cross(a, b)
        normal = normal if normal @ forward > 0 else -normal  # pointing into the view
        planes.append((normal, float(normal @ eye)))
    return planes


def clip_polygon(points: list[FloatArray], half_space: HalfSpace) -> list[FloatArray]:
    """The part of a convex planar polygon inside ``half_space`` (Sutherland–Hodgman)."""
    normal, offset = half_space
    out: list[FloatArray] = []
    for a, b in zip(points, points[1:] + points[:1], strict=True):
        da, db = float(normal @ a) - offset, float(normal @ b) - offset
        if da >= 0.0:
            out.append(a)
        if (da >= 0.0) != (db >= 0.0):
            out.append(a + da / (da - db) * (b - a))
    return out


def visible_box(
    half_extents_m: tuple[float, float, float],
    centre_m: FloatArray,
    eye_m: FloatArray,
    frustum: list[HalfSpace],
) -> Mesh | None:
    """The faces of an axis-aligned box (base frame) that face ``eye_m``, each cut to the
    ``frustum``, in the box's own frame (centred on ``centre_m``); None if none of it is in
    view."""
    half = np.asarray(half_extents_m, dtype=float)
    centre = np.asarray(centre_m, dtype=float)
    mesh = Mesh([], [], [])
    for axis, sign in _FACES:
        normal = np.zeros(3)
        normal[axis] = sign
        face_centre = centre + half * normal
        if normal @ (eye_m - face_centre) <= 0.0:  # turned away: the box hides it
            continue
        a1, a2 = (a for a in range(3) if a != axis)
        polygon = []
        for s1, s2 in ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)):
            p = face_centre.copy()
            p[a1] += s1 * half[a1]
            p[a2] += s2 * half[a2]
            polygon.append(p)
        for half_space in frustum:
            polygon = clip_polygon(polygon, half_space)
            if len(polygon) < 3:
                break
        if len(polygon) < 3:
            continue
        first = len(mesh.vertices)
        mesh.vertices.extend((p - centre).tolist() for p in polygon)
        mesh.normals.extend([normal.tolist()] * len(polygon))
        # The polygon's winding, from its area vector (robust to nearly collinear cut points).
        pairs = zip(polygon, polygon[1:] + polygon[:1], strict=True)
        turn = sum(np.cross(a, b) for a, b in pairs) @ normal
        for i in range(1, len(polygon) - 1):  # a fan; the polygon is convex
            second, third = (i, i + 1) if turn > 0 else (i + 1, i)
            mesh.indices.extend((first, first + second, first + third))
    return mesh if mesh.indices else None
