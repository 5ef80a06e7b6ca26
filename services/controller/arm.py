"""The arm as the joint encoders give it, in the forms the controller's step uses. Pure.

One reading per frame: the joint angles and what forward kinematics makes of them. The law
references its twist at the end effector's origin, a hand vision cannot use is carried along
the end effector's whole pose, acquisition looks across the forearm from the elbow, and the
corner pairing checks its goal postures from the joint angles. Each use but the first is
optional, so that a unit test can give the end effector's position alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common import kinematics as kin
from common.kinematics import FloatArray

ELBOW_FRAME = 2  # index in kinematics.frame_transforms: DH frame 3, at the end of the upper arm


@dataclass(frozen=True, eq=False)
class ArmReading:
    """The encoders' reading of one frame (base frame, metres, radians).

    ``p_ee_base_m``: the end effector's origin, where the twist is referenced.
    ``t_base_ee``: its whole pose (4×4), to carry a hand vision cannot use (None: hold instead).
    ``elbow_base_m``: the elbow, for acquisition's directions (None: image directions alone).
    ``q_rad``: the joint angles, for the corner pairing's goal postures (None: every pairing
    counts).
    ``frames``: their DH frames (``kinematics.frame_transforms``), for keeping the forearm off
    the object (None: it is not kept off)."""

    p_ee_base_m: FloatArray
    t_base_ee: FloatArray | None = None
    elbow_base_m: FloatArray | None = None
    q_rad: FloatArray | None = None
    frames: list[FloatArray] | None = None

    @classmethod
    def from_joints(cls, q_rad: FloatArray | list[float]) -> ArmReading:
        """Every form, from the joint angles through forward kinematics."""
        q = np.array(q_rad, dtype=float)
        frames = kin.frame_transforms(q)
        return cls(frames[-1][:3, 3], frames[-1], frames[ELBOW_FRAME][:3, 3], q, frames)
