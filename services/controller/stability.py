"""Whether a law holds the hand at its goal: local asymptotic stability. Pure.

Near the goal a small displacement ``Δ`` of the hand (integrated twist, camera frame) makes the
error ``e ≈ −L* Δ`` (``ṡ = −L (v, ω)``, :mod:`.interaction`), and the law's twist
``(v, ω) = λ M e`` moves the hand by ``Δ̇ = −λ M L* Δ``: the goal is locally asymptotically
stable when every eigenvalue of ``M L*`` (6×6; ``L* M`` has the same ones, and zeros) has a
positive real part (Chaumette & Hutchinson, Part I: ``L̂⁺ L* > 0``). At the goal the current
features are the desired ones, so dynamic, PMJ and MPJ all invert ``L*`` there and
``M L* = I``; so does points3d with its own Jacobian.

Only the constant strategy can fail it: its frozen matrix built with one depth for every corner
(the thesis's) differs from ``L*`` in its translation columns. The camera sees the target's
square obliquely from the torso, its corners' depths differ by centimetres, and a small
square's interaction matrix barely tells a sideways translation from a turn, so the
difference is amplified: for some target placements ``L_c⁺ L*`` has an eigenvalue with a
negative real part and the law drives the hand away from its own goal (docs/campaign.md).
The controller computes it from what the camera measured (the target's own corner depths) when
it freezes the matrix, and says so in its status.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from common.camera import CameraIntrinsics, pixel_to_normalized
from common.config import ConstantDepth
from common.marker import Marker
from services.controller.interaction import constant_interaction_matrix, interaction_matrix

FloatArray = NDArray[np.float64]


def goal_stability(m_goal: FloatArray, l_goal: FloatArray) -> float:
    """The least real part of the eigenvalues of ``M L*`` (``m_goal`` 6×2N, ``l_goal`` 2N×6):
    above 0 the goal is locally asymptotically stable under ``(v, ω) = λ M e``, 1 for a law
    that inverts ``L*`` exactly; at or below 0 the law leaves its goal."""
    return float(np.linalg.eigvals(np.asarray(m_goal) @ np.asarray(l_goal)).real.min())


def frozen_matrix_stability(l_frozen: FloatArray, desired: Marker, k: CameraIntrinsics) -> float:
    """:func:`goal_stability` of the law ``M = L_frozen⁺`` (2N×6, rows as ``desired``'s
    corners) at the desired features ``desired``, against the interaction matrix there with
    each desired corner's own depth."""
    l_goal = interaction_matrix(pixel_to_normalized(desired.corners_px, k), desired.depth_m)
    return goal_stability(np.linalg.pinv(l_frozen), l_goal)


def constant_goal_stability(desired: Marker, k: CameraIntrinsics, depth: ConstantDepth) -> float:
    """:func:`frozen_matrix_stability` of the constant strategy's matrix built with ``depth``
    from the desired features ``desired``."""
    return frozen_matrix_stability(constant_interaction_matrix(desired, k, depth), desired, k)


def unstable_goal_consequence(stability: float) -> str:
    """What a stability at or below 0 means and what holds the goal instead, for the
    warnings of the controller and of ``umay run``: ``(least real part ... -1.42): the law
    may drive the hand away from it; ...``."""
    return (
        f"(least real part of the eigenvalues of L_c+ L* {stability:.2f}): the law may drive "
        "the hand away from it; controller.constant_depth = 'per_corner' holds it "
        "(docs/campaign.md)"
    )
