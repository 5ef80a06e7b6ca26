"""The simulator's ground truth in the wire format. For evaluation only: nothing in vision or
control may read it. The sim node publishes it; the in-process pipeline (services/pipeline.py)
hands it to the run's judge the same way."""

from __future__ import annotations

from common.kinematics import FloatArray
from common.messages import Header, SimTruth
from services.sim.world import Truth


def truth_message(truth: Truth, header: Header, q_rad: FloatArray) -> SimTruth:
    """``truth`` of the frame ``header`` names, with the joints at ``q_rad``."""
    return SimTruth(
        header=header,
        hand_marker_pose=truth.hand_marker_pose.reshape(-1).tolist(),
        target_marker_pose=truth.target_marker_pose.reshape(-1).tolist(),
        hand_corners_px=truth.hand_corners_px.tolist(),
        target_corners_px=truth.target_corners_px.tolist(),
        ee_position_m=truth.ee_position_m.tolist(),
        joint_position_rad=q_rad.tolist(),
        arm_contact_n=truth.contact_n,
        arm_contact_with=list(truth.contact_with),
    )
