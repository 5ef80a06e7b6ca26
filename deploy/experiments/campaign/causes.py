"""One named cause per campaign run, judged from its row's ground-truth fields (nothing flows
back into the loop): the failure taxonomy of docs/campaign.md."""

from __future__ import annotations

from deploy.experiments.compare.rows import ON_GOAL_M, CompareRow
from services.controller.progress import HELD_BY_CLEARANCE

# A run that failed with a joint this near its limit failed on it: the actuation slows a joint
# linearly inside its last 10° (services/actuation/inverse.py), so the servo's last pixels
# there take many seconds (at 2° from the limit, a fifth of the speed).
JOINT_LIMIT_MARGIN_DEG = 10.0
HAND_OUT_PX = 1.0  # a hand marker corner this near the border (or beyond) has left the image

CAUSES = (
    "converged",
    "refused at start",
    "acquisition failed",
    "collision",
    "stuck",
    "local minimum",
    "joint limit",
    "marker left the image",
    "singularity",
    "timeout",
    "error",
)


def failure_cause(row: CompareRow, manipulability_threshold: float = 0.002) -> str:
    """One named cause per run. ``converged`` (on its goal) or *local minimum* (the image
    error converged, the hand more than 5 mm from its goal; or ``local minimum (image error
    stalled)``: the run ended stalled above the threshold, no limit to blame); *acquisition
    failed*; *error*;
    *collision* with what the arm pressed on (``collision (object)``: it touched the scenery,
    whatever followed, which a servo law cannot undo by itself); *marker left the image* when
    at the end the hand marker was at or past the image border (holding or servoing); a run
    ended holding: *stuck* with what it waited for (from the detail); a run still servoing at
    its end: *joint limit*
    (a joint inside the actuation's slow-down zone at the end, :data:`JOINT_LIMIT_MARGIN_DEG`),
    *singularity* (least manipulability below the actuation's damping threshold), else
    *local minimum (against the clearance)* (stalled with the hand held above the object by
    the clearance, where the law would lower it: the run's detail says so), *local minimum
    (image error stalled)* or *timeout*. The ground-truth fields judge; nothing
    flows back."""
    if row.converged:
        return "converged" if row.on_goal else "local minimum"
    if row.reason == "acquisition_failed":
        return "acquisition failed"
    if row.reason == "error":
        return "error"
    if row.first_contact_s is not None:
        return f"collision ({row.contact_with or 'scenery'})"
    border = row.final_hand_border_px
    if border is not None and border < HAND_OUT_PX:
        return "marker left the image"
    if row.reason == "stuck":
        return f"stuck ({waited_for(row.detail)})"
    margin = row.final_joint_margin_deg
    if margin is not None and margin < JOINT_LIMIT_MARGIN_DEG:
        return "joint limit"
    if row.min_manipulability is not None and row.min_manipulability < manipulability_threshold:
        return "singularity"
    if row.reason != "stalled":
        return "timeout"
    if HELD_BY_CLEARANCE in row.detail:
        return "local minimum (against the clearance)"
    return "local minimum (image error stalled)"


def close_at_end(row: CompareRow) -> bool:
    """The issue's looser criterion: at the run's end the image error under 1 px and the hand
    within 5 mm of its goal, whether or not the controller had declared convergence."""
    pixel, position = row.final_pixel_rms, row.final_position_error_m
    return pixel is not None and position is not None and pixel < 1.0 and position < ON_GOAL_M


def waited_for(detail: str) -> str:
    """``hand partial`` out of a stuck run's detail (see deploy.launch.run_end.stuck_detail)."""
    head = "waiting for: "
    if head not in detail:
        return detail or "?"
    return detail.split(head, 1)[1].split(" (", 1)[0]


def cause_family(cause: str) -> str:
    return cause.split(" (", 1)[0]
