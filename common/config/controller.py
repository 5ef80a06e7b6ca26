"""The scenario's ``[controller]`` table: the IBVS law, its image Jacobian and what it keeps
the arm from."""

from __future__ import annotations

from enum import StrEnum

from pydantic import Field

from common.config.base import Strict
from common.messages import MAX_ANGULAR_RAD_S, MAX_LINEAR_M_S


class JacobianMode(StrEnum):
    """The four image-Jacobian strategies of the thesis (§5.6-5.7), and points3d: the corners'
    3-D positions from the depth camera as features instead of their image points."""

    CONSTANT = "constant"
    DYNAMIC = "dynamic"
    PMJ = "pmj"
    MPJ = "mpj"
    POINTS3D = "points3d"


class ConstantDepth(StrEnum):
    """The depths the constant strategy's frozen interaction matrix is built with."""

    SINGLE = "single"  # one depth for every corner: the thesis's (the target's at the start)
    PER_CORNER = "per_corner"  # each desired corner's own depth, measured at the start


class ClearanceCorrection(StrEnum):
    """How a twist that would lower the hand box onto the object's top face is corrected."""

    # the law's twist changed where its features notice it least (controller/constrained.py)
    LEAST_FEATURE_CHANGE = "least_feature_change"
    LIFT = "lift"  # the least upward velocity added, the rest of the twist kept as it was


class ControllerConfig(Strict):
    mode: JacobianMode = Field(
        JacobianMode.DYNAMIC,
        description="the image Jacobian: constant, dynamic, pmj, mpj (the thesis's four) or "
        "points3d (the corners' 3-D points as features)",
    )
    gain: float = Field(1.0, gt=0.0, le=20.0, description="λ of e' = -λe (1/s)")
    converged_px: float = Field(
        0.25,
        gt=0.0,
        description="pixel RMS of the error averaged over converged_frames frames below which "
        "it converged",
    )
    converged_frames: int = Field(
        5, ge=1, description="frames servoed on a still goal the error is averaged over"
    )
    constant_depth: ConstantDepth = Field(
        ConstantDepth.SINGLE,
        description="constant: build the frozen matrix with one depth for every corner (the "
        "thesis) or with each desired corner's depth measured at the start (per_corner: the "
        "tilt of the target's plane kept; docs/campaign.md)",
    )
    plateau_px: float = Field(
        1.0,
        ge=0.0,
        description="an averaged error below this that has stopped falling for plateau_s also "
        "converged: the goal lies against a joint limit the law cannot pass (0: off)",
    )
    plateau_s: float = Field(
        1.5, gt=0.0, description="sim time without a 5 % fall of the averaged error (s)"
    )
    keep_above_target: bool = Field(
        True, description="keep the hand box above the object's top face (hand_clearance_m)"
    )
    hand_clearance_m: float = Field(
        0.002,
        ge=0.0,
        description="the hand box's corners stay this far above the plane of the red marker "
        "(the object's top face, as vision measures it)",
    )
    keep_forearm_off_object: bool = Field(
        True,
        description="keep the forearm's surface forearm_clearance_m off the object (the prism "
        "under its top face, target.object_side_m wide; services/controller/forearm.py)",
    )
    forearm_clearance_m: float = Field(
        0.002,
        ge=0.0,
        le=0.05,
        description="the least gap between the forearm's surface (its axis less the limb's "
        "radius) and the object (m)",
    )
    clearance_correction: ClearanceCorrection = Field(
        ClearanceCorrection.LEAST_FEATURE_CHANGE,
        description="how a twist that breaks the clearance is corrected: least_feature_change "
        "(the law's least squares under the bound) or lift (straight up, the rest kept)",
    )
    clearance_rate_1_s: float = Field(
        3.0, gt=0.0, description="a corner's height may fall at most this times its margin (1/s)"
    )
    max_linear_m_s: float = Field(
        0.15, gt=0.0, le=MAX_LINEAR_M_S, description="twist clamp, linear (m/s)"
    )
    max_angular_rad_s: float = Field(
        1.0, gt=0.0, le=MAX_ANGULAR_RAD_S, description="twist clamp, angular (rad/s)"
    )
    track_target_motion: bool = Field(
        True,
        description="estimate the target's velocity from its recent views, feed it forward, "
        "and carry a hidden target along it",
    )
    predict_hand_s: float = Field(
        2.0,
        ge=0.0,
        le=60.0,
        description="while vision cannot use the hand marker, servo on its last view carried "
        "along the encoders' motion for at most this long (sim s; 0: hold at once); never "
        "converged on",
    )
    reachable_pairing: bool = Field(
        True,
        description="pair the squares' corners by the least turn among the pairings whose goal "
        "posture an inverse kinematics from the arm's present posture reaches within the joint "
        "limits, checked on the first frame servoed and again once the goal has moved 2 cm "
        "(services/controller/reach.py); false: the least turn whatever the limits",
    )
    acquire: bool = Field(
        True,
        description="when the target cannot be used because something (the hand) is in front "
        "of it, move the hand's image away to uncover it (services/controller/acquisition.py)",
    )
    acquire_after_s: float = Field(
        0.5, ge=0.0, le=60.0, description="hold this long (sim s) before acquiring"
    )
    acquire_attempts: int = Field(
        4, ge=1, le=20, description="image directions tried before acquisition fails"
    )
    acquire_attempt_s: float = Field(
        4.0, gt=0.0, le=60.0, description="sim s one attempt may take at most"
    )
    acquire_max_linear_m_s: float = Field(
        0.06, gt=0.0, le=0.5, description="twist clamp while acquiring, linear (m/s)"
    )
    acquire_gain: float = Field(
        3.0,
        gt=0.0,
        le=20.0,
        description="λ of the acquisition's slide (1/s): the hand slides at its clamp "
        "(acquire_max_linear_m_s) and slows only near the attempt's goal",
    )
    stuck_after_s: float = Field(
        4.0,
        gt=0.0,
        le=3600.0,
        description="a hold this long (sim s) is reported as stuck: umay run ends with it, "
        "umay status shows what it waits for",
    )
    stall_after_s: float = Field(
        5.0,
        gt=0.0,
        le=3600.0,
        description="servoing this long (sim s) without the image error falling 5 % below its "
        "best is reported as stalled (a local minimum of the law, or a limit it pushes "
        "against): umay run ends with it",
    )
