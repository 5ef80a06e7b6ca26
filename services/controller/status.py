"""The controller's own status fields (``umay status``; docs/operations.md renders them)."""

from __future__ import annotations

from pydantic import Field

from common.messages import StatusFields


class ControllerStatus(StatusFields):
    mode: str = Field(description="the Jacobian strategy (`controller.mode`)")
    error_px_rms: float = Field(description="the image error ‖s − s*‖, RMS over the corners (px)")
    converged: bool = Field(description="the hand has settled on its goal")
    holding: bool = Field(description="the last twist was a hold (zero, `valid` false)")
    hold_reason: str = Field(description="why it holds (empty: it does not)")
    phase: str = Field(description="`servoing`, `acquiring` (uncovering the target) or `holding`")
    hold_since_s: float | None = Field(description="when the current hold began (simulated s)")
    holding_for_s: float | None = Field(description="how long it has held (simulated s)")
    stuck: bool = Field(description="held longer than `controller.stuck_after_s`")
    error_best_px: float | None = Field(description="the lowest error of this approach (px)")
    stalled_for_s: float | None = Field(
        description="servoing without the error falling 5 % below its best (simulated s)"
    )
    stalled: bool = Field(description="stalled longer than `controller.stall_after_s`")
    target_remembered: bool = Field(description="servoing on the target's last view")
    target_predicted: bool = Field(
        description="servoing on where its motion says a hidden target went, not yet seen there"
    )
    target_speed_m_s: float = Field(description="the target's estimated speed (m/s)")
    clearance_lifts: int = Field(
        description="twists corrected to keep the hand box above the object's top face or the "
        "forearm off the object"
    )
    hand_predicted: bool = Field(
        description="servoing on the hand's last view carried along the encoders"
    )
    hand_predicted_since_s: float | None = Field(
        description="since when the hand is carried so (simulated s)"
    )
    goal_stability: float | None = Field(
        description="constant: its frozen matrix's local stability at the goal (≤ 0: the law "
        "leaves it)"
    )
    pairing: int | None = Field(
        description="hand corner i goes to target corner (i + pairing) mod 4 (none: not chosen yet)"
    )
    pairings_reachable: list[bool] | None = Field(
        description="which pairings' goal postures the arm reaches from its posture within the "
        "joint limits (none: not checked, every pairing counts)"
    )
