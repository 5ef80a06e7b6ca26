"""The sim's own status fields (``umay status``; docs/operations.md renders them)."""

from __future__ import annotations

from pydantic import Field

from common.messages import StatusFields


class SimStatus(StatusFields):
    clock: str = Field(description="`lockstep` (physics waits for each command) or `realtime`")
    sim_time_s: float = Field(description="simulated time (s)")
    frame_seq: int = Field(description="the next camera frame's number")
    depth_images: int = Field(description="depth images published (`camera.depth_hz`)")
    target_hidden: bool = Field(description="an event hides the target's marker")
    hand_occluded: bool = Field(description="an event's panel stands in front of the hand")
    renderer: str = Field(description="`gl` (OpenGL through EGL) or `tiny` (TinyRenderer)")
    renderer_detail: str = Field(
        description="the OpenGL driver that draws, or why the sim fell back to TinyRenderer"
    )
    render_ms: float = Field(description="the last frame's render, Kinect model included (ms)")
    dropped_frames: int = Field(description="realtime: camera frames missed while rendering")
    watchdog_stops: int = Field(
        description="motors stopped for want of a command within `sim.command_watchdog_s`"
    )
    motor_clamps: int = Field(description="commands beyond the motors' own speed limit")
    frames_by_ref: int = Field(
        description="camera frames (colour and depth) sent by reference through the "
        "shared-memory ring"
    )
    frames_by_copy: int = Field(description="camera frames sent whole (no ring)")
    frames_in_place: int = Field(
        description="of those by reference, drawn straight into their ring slot"
    )
    frames_copied_to_ring: int = Field(
        description="of those by reference, copied into their slot (TinyRenderer without the "
        "Kinect model); the rest are lockstep resends of the same reference"
    )
    frames_copy_reason: str = Field(description="why frames go whole (empty: they do not)")
    whole_frames_served: int = Field(
        description="whole frames sent to subscribers that could not map the ring"
    )
    real_time_factor: float = Field(description="simulated time over wall time since the start")
