"""The scenario's ``[vision]`` table: how the markers are segmented and measured."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from common.config.base import Strict

# A colour, 0..255 per channel.
Rgb = Annotated[list[Annotated[int, Field(ge=0, le=255)]], Field(min_length=3, max_length=3)]


class HsvRange(Strict):
    """Inclusive OpenCV HSV range (H in 0..179, S and V in 0..255). Red wraps: give two."""

    lower: Annotated[list[int], Field(min_length=3, max_length=3)]
    upper: Annotated[list[int], Field(min_length=3, max_length=3)]

    @field_validator("lower", "upper")
    @classmethod
    def _in_range(cls, v: list[int]) -> list[int]:
        if not (0 <= v[0] <= 179 and 0 <= v[1] <= 255 and 0 <= v[2] <= 255):
            raise ValueError("expected H in 0..179, S and V in 0..255")
        return v

    @model_validator(mode="after")
    def _lower_below_upper(self) -> HsvRange:
        # An empty range matches nothing: a marker never found (red's wrap is two ranges).
        if any(lo > up for lo, up in zip(self.lower, self.upper, strict=True)):
            raise ValueError(f"lower {self.lower} above upper {self.upper} in some channel")
        return self


class VisionConfig(Strict):
    segmentation: Literal["hsv", "rgb"] = Field(
        "hsv",
        description="hsv: hue bands (exposure changes leave them alone); rgb: a reference "
        "colour per marker and a tolerance (the thesis's first method)",
    )
    # HSV: hue bands with a high saturation floor and a low value floor, so that exposure
    # changes (value) leave the masks alone; low-saturation table, arm and floor stay out.
    red_hsv: list[HsvRange] = Field(
        min_length=1,
        description="the red marker's OpenCV HSV ranges (H 0..179; red wraps, so two)",
        default_factory=lambda: [
            HsvRange(lower=[0, 120, 30], upper=[8, 255, 255]),
            HsvRange(lower=[172, 120, 30], upper=[179, 255, 255]),
        ],
    )
    green_hsv: list[HsvRange] = Field(
        min_length=1,
        description="the green marker's HSV ranges",
        default_factory=lambda: [HsvRange(lower=[45, 120, 30], upper=[75, 255, 255])],
    )
    # The orientation cue (marker.orientation_cue): a saturated blue, a hue that neither marker,
    # the table, the arm, the floor nor the blue-grey block (saturation below 100) reaches.
    # Looked for only inside a marker's square, in both segmentation modes.
    cue_hsv: list[HsvRange] = Field(
        min_length=1,
        description="the orientation cue's HSV ranges, looked for inside each marker",
        default_factory=lambda: [HsvRange(lower=[100, 120, 30], upper=[130, 255, 255])],
    )
    # RGB mode (the thesis's first method): a reference colour per marker and a per-channel
    # tolerance, calibrated on the markers as the default scene renders them (diffuse light).
    red_rgb: Rgb = Field(
        [130, 12, 12], description="rgb: the red marker's reference colour (0..255)"
    )
    green_rgb: Rgb = Field(
        [15, 115, 22], description="rgb: the green marker's reference colour (0..255)"
    )
    rgb_tolerance: int = Field(
        50, ge=1, le=255, description="rgb: how far each channel may be from the reference"
    )
    min_area_px: int = Field(
        60,
        ge=4,
        description="a smaller blob is not measured as a whole square; the fit of a partly "
        "hidden marker from its visible edges may still find it",
    )
    occlusion_ring_px: int = Field(
        5,
        ge=1,
        le=30,
        description="invalid depth pixels next to a marker count as something in front of it "
        "when a closer surface lies this near (past the band a depth camera leaves invalid "
        "along an occluder's edge)",
    )
    max_depth_age_s: float = Field(
        1.2,
        gt=0.0,
        le=60.0,
        description="a colour frame is paired with the newest depth image no older than this",
    )
