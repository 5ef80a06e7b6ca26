"""Vision's own status fields (``umay status``; docs/operations.md renders them)."""

from __future__ import annotations

from pydantic import Field

from common.messages import StatusFields


class VisionStatus(StatusFields):
    markers: dict[str, str] = Field(
        description="each marker's state in the last frame: `visible`, `partial`, `lost` or "
        "`no_depth`"
    )
    lost_reasons: dict[str, str] = Field(description="why each marker is not usable (empty: it is)")
    depth_age_s: float | None = Field(
        description="the depth image's age at the last colour frame (simulated s; none: no "
        "depth image yet)"
    )
    depth_waits: int = Field(
        description="waits begun for a late depth image (a newer colour frame takes over a wait)"
    )
    depth_missed: int = Field(
        description="colour frames measured without the depth image they named: after a wait "
        "ran out, or while the depth stream is late"
    )
    frames_by_ref: int = Field(description="camera frames read in place in the sim's ring")
    frames_by_copy: int = Field(description="camera frames received whole")
    frames_fetched: int = Field(
        description="of those whole, fetched from the sim (its ring was out of reach)"
    )
    frames_overwritten: int = Field(
        description="measurements dropped: a frame's ring slot was written again while vision "
        "read it"
    )
