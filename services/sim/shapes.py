"""The scene's visual geometry as plain data, read from the pybullet world that physics uses.

pybullet holds the one description of every body (the URDF of the arm, the boxes of the world);
every renderer draws from it: TinyRenderer inside pybullet, the OpenGL renderer
(:mod:`services.sim.gl_renderer`) through :func:`visual_shapes` and :func:`shape_poses`. Boxes
and cylinders are rebuilt here as triangle meshes at their true size (TinyRenderer draws a
cylinder from Bullet's collision hull, about a millimetre fat).

Meshes are pure numpy: :func:`box_mesh` and :func:`cylinder_mesh` give vertices and outward
normals in the shape's own frame, three vertices a triangle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.kinematics import homogeneous, rotation_from_quaternion
from services.sim.bullet import BulletClient, pybullet

FloatArray = np.ndarray

CYLINDER_SEGMENTS = 64  # a 22 mm radius limb strays 0.03 mm from its circle


@dataclass(frozen=True)
class VisualShape:
    """One visual shape of one link: ``kind`` "box" (``size_m`` full extents x, y, z) or
    "cylinder" (``size_m`` = (length along z, radius)), placed at ``local_pose`` (4×4) in its
    link's frame, drawn in ``rgba`` and labelled ``segment_id`` in the id image (pybullet's
    encoding: body + ((link + 1) << 24))."""

    body: int
    link: int  # -1: the body's base
    kind: str
    size_m: tuple[float, ...]
    local_pose: FloatArray
    rgba: tuple[float, float, float, float]

    @property
    def segment_id(self) -> int:
        return self.body + ((self.link + 1) << 24)


def pose_matrix(position: tuple[float, ...], quaternion_xyzw: tuple[float, ...]) -> FloatArray:
    """4×4 homogeneous transform of a pybullet (position, quaternion x y z w)."""
    return homogeneous(rotation_from_quaternion(*quaternion_xyzw), np.asarray(position, float))


def body_ids(client: BulletClient) -> tuple[int, ...]:
    """The unique ids of the bodies in the world now (a body made or removed changes it)."""
    return tuple(client.getBodyUniqueId(i) for i in range(client.getNumBodies()))


def visual_shapes(client: BulletClient) -> list[VisualShape]:
    """Every box and cylinder visual of every body. Meshes (TinyRenderer's cut scenery) are
    refused: the world builds whole boxes for any other renderer."""
    shapes = []
    for body in body_ids(client):
        for data in client.getVisualShapeData(body):
            link, geometry, size = data[1], data[2], tuple(float(v) for v in data[3])
            if geometry == pybullet.GEOM_BOX:
                kind, dims = "box", size
            elif geometry == pybullet.GEOM_CYLINDER:
                kind, dims = "cylinder", size[:2]
            else:
                raise ValueError(f"body {body} link {link}: visual geometry {geometry} not drawn")
            rgba = tuple(float(v) for v in data[7])
            local = pose_matrix(data[5], data[6])
            shapes.append(VisualShape(body, link, kind, dims, local, rgba))  # type: ignore[arg-type]
    return shapes


def shape_poses(client: BulletClient, shapes: list[VisualShape]) -> list[FloatArray]:
    """World pose (4×4) of each shape now: its link's frame times its local pose.

    pybullet gives a visual's local frame relative to the link's inertial frame; it is also
    what getLinkState's first pose and a base's pose are, so the two compose exactly."""
    frames: dict[tuple[int, int], FloatArray] = {}
    for shape in shapes:
        key = (shape.body, shape.link)
        if key in frames:
            continue
        if shape.link < 0:
            position, orientation = client.getBasePositionAndOrientation(shape.body)
        else:
            state = client.getLinkState(shape.body, shape.link, computeForwardKinematics=True)
            position, orientation = state[0], state[1]
        frames[key] = pose_matrix(position, orientation)
    return [frames[(s.body, s.link)] @ s.local_pose for s in shapes]


def box_mesh(size_m: tuple[float, ...]) -> tuple[FloatArray, FloatArray]:
    """Vertices and outward normals (float32, 36×3 each) of a box of full extents ``size_m``
    centred on its frame."""
    half = np.asarray(size_m, dtype=np.float64) / 2
    vertices, normals = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            u, v = np.eye(3)[(axis + 1) % 3], np.eye(3)[(axis + 2) % 3]
            centre = n * half[axis]
            signs = ((-1, -1), (1, -1), (1, 1), (-1, 1))
            quad = [centre + (a * u + b * v) * half for a, b in signs]
            for i in (0, 1, 2, 0, 2, 3):
                vertices.append(quad[i])
                normals.append(n)
    return np.asarray(vertices, np.float32), np.asarray(normals, np.float32)


def cylinder_mesh(
    length_m: float, radius_m: float, segments: int = CYLINDER_SEGMENTS
) -> tuple[FloatArray, FloatArray]:
    """Vertices and normals (float32) of a cylinder along z, centred on its frame: the side with
    smooth normals, and both caps."""
    angles = np.linspace(0.0, 2 * np.pi, segments + 1)
    ring = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
    z = np.array([0.0, 0.0, length_m / 2])
    vertices, normals = [], []
    for k in range(segments):
        a, b = ring[k], ring[k + 1]
        lo_a, lo_b = a * radius_m - z, b * radius_m - z
        hi_a, hi_b = a * radius_m + z, b * radius_m + z
        vertices += [lo_a, lo_b, hi_b, lo_a, hi_b, hi_a]
        normals += [a, b, b, a, b, a]
        vertices += [z, hi_a, hi_b, -z, lo_b, lo_a]  # caps
        normals += [np.array([0.0, 0.0, 1.0])] * 3 + [np.array([0.0, 0.0, -1.0])] * 3
    return np.asarray(vertices, np.float32), np.asarray(normals, np.float32)


def shape_mesh(shape: VisualShape) -> tuple[FloatArray, FloatArray]:
    """The triangle mesh of ``shape`` in its own frame."""
    if shape.kind == "box":
        return box_mesh(shape.size_m)
    return cylinder_mesh(shape.size_m[0], shape.size_m[1])
