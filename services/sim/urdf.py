"""URDF of the UMay robot (right arm and hand), generated from the DH table.

The torso they hang from never moves, so the world draws it as scenery (cut to what the
camera sees, :mod:`services.sim.scenery`) from :data:`TORSO_SIZE_M` and :data:`TORSO_CENTRE_M`.

Each arm link frame *is* the DH frame of the same index: the modified DH transform
``Rx(α)·Tx(a)·Rz(θ)·Tz(d)`` equals ``[Rx(α)·Tx(a)·Tz(d)]·Rz(θ)`` (rotation and translation
along z commute), so joint_i's fixed origin is ``Rx(α)·Tx(a)·Tz(d)`` and it turns about its z.
``base_link`` is DH frame 0 and ``ee_link`` is DH frame 6.
"""

from __future__ import annotations

import numpy as np

from common import kinematics as kin

GREY = "0.75 0.75 0.78 1"
TORSO_COLOUR = (0.35, 0.37, 0.42, 1.0)
# The torso, in the base frame: the right shoulder (DH frame 0) sits near its upper right
# corner, 6 cm below the top; its front face (x = 0.01) carries the camera at mid-width.
TORSO_SIZE_M = (0.14, 0.48, 0.26)
TORSO_CENTRE_M = (-0.06, -0.14, -0.13)
# The table, in the base frame (y up): its top, the box under it; the object stands on it.
TABLE_TOP_Y_M = -0.40
TABLE_SIZE_M = (0.56, 0.04, 0.90)
TABLE_CENTRE_M = (0.42, TABLE_TOP_Y_M - TABLE_SIZE_M[1] / 2, 0.0)
SKIN = "0.92 0.90 0.86 1"
GREEN = "0.10 0.75 0.15 1"
# The orientation cue on both markers (config marker.orientation_cue): a saturated blue that
# neither marker, the skin, the arm, the table nor the floor produce (vision's cue_hsv).
CUE_RGBA = (0.10, 0.25, 0.90, 1.0)
# The cue's thickness: it stands on the marker's face, its top this far nearer the camera, so
# that both renderers draw it over the marker (depth test) rather than fighting with it.
CUE_HEIGHT_M = 0.0002


def _origin(xyz: np.ndarray, rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> str:
    x, y, z = (float(v) for v in xyz)
    return f'<origin xyz="{x:.9f} {y:.9f} {z:.9f}" rpy="{rpy[0]:.9f} {rpy[1]:.9f} {rpy[2]:.9f}"/>'


def _material(rgba: str) -> str:
    name = "c" + rgba.replace(" ", "_")
    return f'<material name="{name}"><color rgba="{rgba}"/></material>'


def _box_visual(size: tuple[float, float, float], xyz: np.ndarray, rgba: str, collide: bool) -> str:
    geom = f'<geometry><box size="{size[0]} {size[1]} {size[2]}"/></geometry>'
    vis = f"<visual>{_origin(xyz)}{geom}{_material(rgba)}</visual>"
    col = f"<collision>{_origin(xyz)}{geom}</collision>" if collide else ""
    return vis + col


def _cylinder_between(p0: np.ndarray, p1: np.ndarray, radius: float, rgba: str) -> str:
    """A cylinder visual/collision from p0 to p1 (link frame), for upper arm and forearm."""
    d = p1 - p0
    length = float(np.linalg.norm(d))
    if length < 1e-6:
        return ""
    mid = (p0 + p1) / 2
    z = d / length
    # rpy that maps the cylinder's z axis onto d: yaw about z, then pitch about y.
    pitch = float(np.arccos(np.clip(z[2], -1.0, 1.0)))
    yaw = float(np.arctan2(z[1], z[0]))
    geom = f'<geometry><cylinder radius="{radius}" length="{length:.9f}"/></geometry>'
    o = _origin(mid, (0.0, pitch, yaw))
    return f"<visual>{o}{geom}{_material(rgba)}</visual><collision>{o}{geom}</collision>"


def _inertial(mass: float) -> str:
    return (
        f'<inertial><mass value="{mass}"/>'
        '<inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial>'
    )


def cue_box(marker_pose: np.ndarray, size_m: float) -> tuple[np.ndarray, tuple[float, ...]]:
    """Centre (in the marker pose's parent frame) and full extents along the marker's x, y, z
    of the orientation cue: a square of :data:`common.kinematics.CUE_SIDE_FRACTION` of the side
    at :func:`common.kinematics.cue_centre_in_marker`, standing :data:`CUE_HEIGHT_M` on the
    marker's face."""
    local = kin.cue_centre_in_marker(size_m) + np.array([0.0, 0.0, CUE_HEIGHT_M / 2])
    side = kin.CUE_SIDE_FRACTION * size_m
    return (marker_pose @ np.append(local, 1.0))[:3], (side, side, CUE_HEIGHT_M)


def robot_urdf(marker_size_m: float, orientation_cue: bool = False) -> str:
    """The URDF text. ``base_link`` (the shoulder) is in the base frame (x forward, y up,
    z right). ``orientation_cue``: the hand's marker carries the cue (:func:`cue_box`)."""
    dh = kin.UMAY_DH
    links: list[str] = []
    joints: list[str] = []
    shoulder = _box_visual((0.05, 0.04, 0.05), np.array([0.0, 0.0, 0.0]), GREY, False)
    links.append(f'<link name="base_link">{_inertial(0.0)}{shoulder}</link>')

    # Where the next joint's origin is, expressed in link i's frame (for drawing the limbs).
    names = ["link_1", "link_2", "link_3", "link_4", "link_5", "ee_link"]
    for i, row in enumerate(dh):
        parent = "base_link" if i == 0 else names[i - 1]
        xyz = kin.rot_x(row.alpha_prev_rad) @ np.array([row.a_prev_m, 0.0, row.d_m])
        lower, upper = kin.JOINT_LOWER_RAD[i], kin.JOINT_UPPER_RAD[i]
        vel = kin.JOINT_VELOCITY_LIMIT_RAD_S[i]
        joints.append(
            f'<joint name="joint_{i + 1}" type="revolute"><parent link="{parent}"/>'
            f'<child link="{names[i]}"/>{_origin(xyz, (row.alpha_prev_rad, 0.0, 0.0))}'
            f'<axis xyz="0 0 1"/><limit lower="{lower:.9f}" upper="{upper:.9f}" effort="100" '
            f'velocity="{vel}"/></joint>'
        )
    # Limb shapes: each link draws a segment to the next joint's origin.
    shapes = {name: "" for name in names}
    for i in range(len(dh) - 1):
        nxt = dh[i + 1]
        p_next = kin.rot_x(nxt.alpha_prev_rad) @ np.array([nxt.a_prev_m, 0.0, nxt.d_m])
        if np.linalg.norm(p_next) > 0.03:
            shapes[names[i]] += _cylinder_between(np.zeros(3), p_next, kin.LIMB_RADIUS_M, GREY)
    # The upper arm: link_2 → joint_3 origin (0.264 m); forearm: link_4 → joint_5 (0.212 m).
    # The hand: a box on ee_link, the green marker on its back (visual only).
    hand_centre = np.array([0.0, kin.HAND_OFFSET_M + kin.HAND_LENGTH_M / 2, 0.0])
    shapes["ee_link"] += _box_visual(
        (kin.HAND_THICKNESS_M, kin.HAND_LENGTH_M, kin.HAND_WIDTH_M), hand_centre, SKIN, True
    )
    marker = kin.hand_marker_in_ee()
    marker_centre = marker[:3, 3] - marker[:3, 2] * kin.MARKER_THICKNESS_M / 2
    geom = (
        f'<geometry><box size="{kin.MARKER_THICKNESS_M} {marker_size_m} {marker_size_m}"/>'
        "</geometry>"
    )
    # The marker box is axis-aligned in ee_link: thin along x6 (its normal), square in y6-z6.
    shapes["ee_link"] += f"<visual>{_origin(marker_centre)}{geom}{_material(GREEN)}</visual>"
    if orientation_cue:
        centre, (side, _, height) = cue_box(marker, marker_size_m)
        # marker x, y, z are ee_link's y, z, x: the box's extents in ee_link's axes
        cue = f'<geometry><box size="{height} {side} {side}"/></geometry>'
        rgba = " ".join(f"{c:g}" for c in CUE_RGBA)
        shapes["ee_link"] += f"<visual>{_origin(centre)}{cue}{_material(rgba)}</visual>"
    for name in names:
        links.append(f'<link name="{name}">{_inertial(0.3)}{shapes[name]}</link>')
    body = "\n".join(links + joints)
    return f'<?xml version="1.0"?>\n<robot name="umay">\n{body}\n</robot>\n'


MIN_BLOCK_HEIGHT_M = 0.005  # a lower object is not built: the marker lies on the table


def object_block(target_pose: np.ndarray) -> tuple[np.ndarray, float]:
    """The object under the red marker (pose ``target_pose``, base frame): the centre of the
    block from the table's top up to the marker's underside, and its height (m; ≤ 0: none)."""
    top_y = float(target_pose[1, 3]) - kin.MARKER_THICKNESS_M
    centre = np.array([target_pose[0, 3], (top_y + TABLE_TOP_Y_M) / 2, target_pose[2, 3]])
    return centre, top_y - TABLE_TOP_Y_M
