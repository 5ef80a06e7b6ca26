"""Wire format: one pydantic model per payload. Every message carries a :class:`Header`.

Units are in the field names (``_m``, ``_rad``, ``_px``, ``_s``). Every float must be finite
(``allow_inf_nan=False``) and every array has a fixed shape, so a message that validates is
safe to act on. Images travel as raw bytes with their shape and dtype (:class:`ImageData`).
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, model_validator

from common.camera import CameraIntrinsics
from common.kinematics import N_JOINTS

# Sane ranges: a value outside them is a fault, not a command to follow.
PIXEL_LIMIT_PX = 1e4
Pixel = Annotated[float, Field(ge=-PIXEL_LIMIT_PX, le=PIXEL_LIMIT_PX)]
Metres = Annotated[float, Field(ge=-50.0, le=50.0)]
Depth = Annotated[float, Field(ge=0.0, le=50.0)]
Angle = Annotated[float, Field(ge=-7.0, le=7.0)]  # rad, a little over ±2π
JointRate = Annotated[float, Field(ge=-20.0, le=20.0)]  # rad/s
MAX_LINEAR_M_S = 5.0  # a twist's components on the wire (the controller's clamps stay within)
MAX_ANGULAR_RAD_S = 20.0
LinearRate = Annotated[float, Field(ge=-MAX_LINEAR_M_S, le=MAX_LINEAR_M_S)]  # m/s
AngularRate = Annotated[float, Field(ge=-MAX_ANGULAR_RAD_S, le=MAX_ANGULAR_RAD_S)]  # rad/s

Vec2 = Annotated[list[Pixel], Field(min_length=2, max_length=2)]
Vec3 = Annotated[list[Metres], Field(min_length=3, max_length=3)]
Joints = Annotated[list[Angle], Field(min_length=N_JOINTS, max_length=N_JOINTS)]
JointRates = Annotated[list[JointRate], Field(min_length=N_JOINTS, max_length=N_JOINTS)]
Corners2 = Annotated[list[Vec2], Field(min_length=4, max_length=4)]
Corners3 = Annotated[list[Vec3], Field(min_length=4, max_length=4)]
Depths4 = Annotated[list[Depth], Field(min_length=4, max_length=4)]
Pose16 = Annotated[list[Metres], Field(min_length=16, max_length=16)]


class Message(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Header(Message):
    """Traceability: ``frame_seq`` is the camera frame a message derives from (-1: none)."""

    seq: int = Field(ge=0, description="per-publisher sequence number")
    sim_time_s: float = Field(ge=0.0, le=1e7, description="simulation time of the source data")
    send_time_s: float = Field(
        ge=0.0, le=1e11, description="wall-clock time at publication (Unix s)"
    )
    frame_seq: int = Field(-1, ge=-1, description="camera frame this message derives from")
    recv_time_s: float = Field(
        0.0,
        ge=0.0,
        le=1e11,
        description="wall-clock time (Unix s) at which the publisher received the input that "
        "completed this message's inputs (0: none, e.g. a camera frame); with send_time_s it "
        "splits latency into transport and processing per hop",
    )
    run: int = Field(
        0,
        ge=0,
        lt=1 << 62,
        description="the sim's run the message derives from: drawn by the sim at its start, "
        "copied by every service from its input (common.runs); a new one means the sim "
        "restarted and frame numbers began again (0: not stamped)",
    )


ImageDtype = Literal["uint8", "float32"]
ITEMSIZE: dict[str, int] = {"uint8": 1, "float32": 4}  # bytes per element of each ImageDtype


class ImageSpec(Message):
    """Shape and dtype of a raw C-contiguous image (what a frame's header says of its pixels)."""

    shape: Annotated[list[int], Field(min_length=2, max_length=3)]
    dtype: ImageDtype

    @model_validator(mode="after")
    def _shape_in_range(self) -> ImageSpec:
        if any(d <= 0 or d > 8192 for d in self.shape):
            raise ValueError(f"image shape {self.shape} out of range (1..8192 per axis)")
        return self

    @property
    def nbytes(self) -> int:
        # Plain Python: np.prod and np.dtype cost ~10 µs a call, a few calls per frame per hop.
        return math.prod(self.shape) * ITEMSIZE[self.dtype]


class ImageData(ImageSpec):
    """A raw image: C-contiguous ``data`` of ``shape`` and ``dtype``.

    ``data`` is ``bytes`` when validated from a payload by pydantic, or a read-only
    ``memoryview`` (no copy) when made by :meth:`view_of` or decoded by :mod:`common.codec`
    from the frame layout (a view into the received payload, or into a slot of the
    publisher's shared-memory ring for a frame sent by reference: see :meth:`intact`)."""

    data: bytes
    # (FrameRef, RingReader) of common.frame_ring when ``data`` is a view of a ring's slot.
    _ring: tuple[Any, Any] | None = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _size_matches_shape(self) -> ImageData:
        if len(self.data) != self.nbytes:
            raise ValueError(f"image data has {len(self.data)} bytes, shape needs {self.nbytes}")
        return self

    @classmethod
    def from_array(cls, array: np.ndarray) -> ImageData:
        """A copy of ``array``'s pixels (validated like a received image)."""
        a = np.ascontiguousarray(array)
        return cls(shape=list(a.shape), dtype=str(a.dtype), data=a.tobytes())

    @classmethod
    def view_of(cls, array: np.ndarray) -> ImageData:
        """``array``'s pixels without a copy (checked as :meth:`from_array` would check
        them): ``array`` must not change while the message is in use."""
        a = np.ascontiguousarray(array)
        spec = ImageSpec(shape=list(a.shape), dtype=str(a.dtype))  # type: ignore[arg-type]
        view = memoryview(a).cast("B").toreadonly()
        return cls.from_view(spec, view)

    @classmethod
    def from_view(cls, spec: ImageSpec, data: memoryview) -> ImageData:
        """An image of a validated ``spec`` over ``data`` (no copy); raises ValueError when the
        sizes differ."""
        if len(data) != spec.nbytes:
            raise ValueError(f"image data has {len(data)} bytes, shape needs {spec.nbytes}")
        return cls.model_construct(shape=list(spec.shape), dtype=spec.dtype, data=data)

    def to_array(self) -> np.ndarray:
        """Read-only view on the bytes (no copy)."""
        return np.frombuffer(self.data, dtype=self.dtype).reshape(self.shape)

    def in_ring(self, ref: Any, rings: Any) -> None:
        """Say that ``data`` is a view of the ring slot ``ref`` (a ``FrameRef``) that
        ``rings`` (a ``RingReader``) mapped: what :mod:`common.codec` does for a frame sent
        by reference."""
        self._ring = (ref, rings)

    @property
    def ring_ref(self) -> Any:
        """The ``FrameRef`` of the ring slot this image is a view of; None for an image that
        owns its bytes or views a payload."""
        return None if self._ring is None else self._ring[0]

    def intact(self) -> bool:
        """Whether the pixels are still the frame's. Always for an image that owns its bytes
        or views a received payload; for a view of a ring slot, whether the publisher has not
        begun to write another frame into that slot. A consumer of a frame sent by reference
        asks this once it is done with the pixels, and throws away what it computed from
        them when the answer is no."""
        return self._ring is None or self._ring[1].intact(self._ring[0])

    def superseded(self) -> bool:
        """Whether a later frame of the same stream is already being written (a view of a ring
        slot whose publisher has begun the frame after it): a consumer that has fallen behind
        skips to that one. Never for an image that owns its bytes or views a payload: nothing
        tells, and the frame is used."""
        return self._ring is not None and self._ring[1].superseded(self._ring[0])


class RgbFrame(Message):
    """Colour image (uint8, H×W×3) from the torso camera.

    The depth stream may run slower than this one; every depth image is taken together with a
    colour frame. ``depth_frame_seq`` is the ``frame_seq`` of the newest depth image taken at
    or before this frame (-1: none yet), so a consumer knows which depth image to wait for (as
    a driver's timestamps would tell it) and pairing stays deterministic."""

    header: Header
    intrinsics: CameraIntrinsics
    rgb: ImageData
    depth_frame_seq: int = Field(-1, ge=-1)

    @model_validator(mode="after")
    def _consistent(self) -> RgbFrame:
        h, w = self.intrinsics.height_px, self.intrinsics.width_px
        if self.rgb.shape != [h, w, 3] or self.rgb.dtype != "uint8":
            raise ValueError(
                f"rgb must be uint8 [{h}, {w}, 3], got {self.rgb.dtype} {self.rgb.shape}"
            )
        return self


class DepthFrame(Message):
    """Depth image (float32, metres along the optical axis, H×W; 0 = no measurement),
    registered to the colour camera: same viewpoint and field of view, possibly at a lower
    resolution (``intrinsics`` are the depth image's own). ``header.frame_seq`` is the colour
    frame taken at the same instant."""

    header: Header
    intrinsics: CameraIntrinsics
    depth_m: ImageData

    @model_validator(mode="after")
    def _consistent(self) -> DepthFrame:
        h, w = self.intrinsics.height_px, self.intrinsics.width_px
        if self.depth_m.shape != [h, w] or self.depth_m.dtype != "float32":
            raise ValueError(
                f"depth_m must be float32 [{h}, {w}], got {self.depth_m.dtype} {self.depth_m.shape}"
            )
        return self


class JointState(Message):
    """Encoder readings of joint_1..joint_6, sampled with camera frame ``header.frame_seq``."""

    header: Header
    position_rad: Joints
    velocity_rad_s: JointRates


MarkerState = Literal["visible", "partial", "lost", "no_depth"]


# A usable marker (corners and depths acted on) lies at least this far in front of the camera
# and covers at least this much of the image: less is a fault, not a measurement.
MIN_USABLE_DEPTH_M = 0.01
MIN_USABLE_AREA_PX2 = 1.0


def usable_depths(depths_m: np.ndarray) -> bool:
    """Depths a usable marker may carry: finite, and at least :data:`MIN_USABLE_DEPTH_M`."""
    return bool(np.all(np.isfinite(depths_m) & (depths_m >= MIN_USABLE_DEPTH_M)))


def is_usable(state: str, fitted: bool) -> bool:
    """A marker's corners and depths can be acted on: seen whole, or partly hidden and fitted
    from what is seen (one rule for vision, the wire format and the controller)."""
    return state == "visible" or (state == "partial" and fitted)


class MarkerFeatures(Message):
    """One square marker: four corners in canonical order, their depths and 3-D points.

    ``state``: ``visible`` (the whole square, corners and depths usable), ``partial`` (part of
    it is seen: hidden by something in front, cut by the image border, or not a clean
    quadrilateral), ``lost`` (not seen), ``no_depth`` (seen whole, but no depth measurement
    recent enough). The arrays are zeros unless the state is ``visible``, or ``fitted`` is
    set: a ``partial`` marker whose corners (hidden ones included) were found by fitting its
    known square, on its known plane, to the edges of it that are seen. ``occluded``: the
    depth image (or, between depth images, the hand marker) shows something in front of the
    marker or of where it was last seen, i.e. it is hidden, not gone; None on a ``lost``
    marker vision has no view of to look in front of (none measured with a depth image since
    it started: a restarted vision cannot tell hidden from gone).

    Vision and the controller work on :class:`common.marker.Marker` (the same fields as
    arrays); ``Marker.to_wire`` / ``Marker.from_wire`` convert.
    """

    state: MarkerState
    corners_px: Corners2
    depth_m: Depths4
    depth_sigma_m: Depths4 = Field(description="1-σ uncertainty of each corner depth")
    points_m: Corners3 = Field(description="corners in the camera optical frame")
    occluded: bool | None = Field(
        False, description="something in front of it: hidden, not gone (None: cannot tell)"
    )
    fitted: bool = False
    reason: str = Field("", max_length=200, description="why not visible")

    @model_validator(mode="after")
    def _usable_can_be_acted_on(self) -> MarkerFeatures:
        # The controller divides by these depths and fits planes to these points: a usable
        # marker at zero depth or collapsed to a point would end it with a NaN twist.
        if not self.usable:
            return self
        points = self.points_m
        nearest_z = min(points[0][2], points[1][2], points[2][2], points[3][2])  # four corners
        if min(self.depth_m) < MIN_USABLE_DEPTH_M or nearest_z < MIN_USABLE_DEPTH_M:
            raise ValueError(
                f"a {self.state} marker needs every corner at least {MIN_USABLE_DEPTH_M} m in "
                "front of the camera (depth_m, points_m)"
            )
        if quad_area(self.corners_px) < MIN_USABLE_AREA_PX2:
            raise ValueError(f"a {self.state} marker's corners_px enclose no area")
        if _diagonals_cross(self.points_m) <= 0.0:
            raise ValueError(f"a {self.state} marker's points_m enclose no area")
        return self

    @property
    def visible(self) -> bool:
        return self.state == "visible"

    @property
    def usable(self) -> bool:
        return is_usable(self.state, self.fitted)


def _diagonals_cross(points: list[list[float]]) -> float:
    """|d1 × d2|² of a 3-D quadrilateral's diagonals: zero when its corners enclose no area.
    Plain Python: numpy's calls on four points cost several times more, on every message."""
    (x0, y0, z0), (x1, y1, z1), (x2, y2, z2), (x3, y3, z3) = points
    a0, a1, a2 = x2 - x0, y2 - y0, z2 - z0
    b0, b1, b2 = x3 - x1, y3 - y1, z3 - z1
    c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    return c0 * c0 + c1 * c1 + c2 * c2


def quad_area(corners: list[list[float]]) -> float:
    """Area of a quadrilateral (shoelace, either winding), in the corners' units squared.
    Written out: it runs on every marker of every Features message."""
    (x0, y0), (x1, y1), (x2, y2), (x3, y3) = corners
    twice = (x0 * y3 - x3 * y0) + (x1 * y0 - x0 * y1) + (x2 * y1 - x1 * y2) + (x3 * y2 - x2 * y3)
    return 0.5 * abs(twice)


class Features(Message):
    """Output of vision: the hand (green) and target (red) markers of one colour frame.

    ``depth_age_s``: how much older (sim time) the depth image used is than the colour frame
    (0: taken together); None when no depth image was available."""

    header: Header
    intrinsics: CameraIntrinsics
    hand: MarkerFeatures
    target: MarkerFeatures
    depth_age_s: float | None = Field(None, ge=0.0, le=1e7)


class EndEffectorTwist(Message):
    """Commanded end-effector twist in the arm base frame: ``linear_m_s`` is the velocity of
    the DH-frame-6 origin, ``angular_rad_s`` the angular velocity."""

    header: Header
    linear_m_s: Annotated[list[LinearRate], Field(min_length=3, max_length=3)]
    angular_rad_s: Annotated[list[AngularRate], Field(min_length=3, max_length=3)]
    valid: bool = Field(description="False: hold (features missing); the twist is zero")
    hold_reason: str = Field("", max_length=200, description="why it holds, when not valid")
    mode: str = Field(max_length=32)
    error_px_rms: float = Field(
        ge=0.0, le=1e5, description="RMS of e = s - s* over the 8 coordinates"
    )
    converged: bool
    lifted: bool = Field(
        False,
        description="corrected to keep the hand's box above the object's top face or the "
        "forearm off the object (controller.keep_above_target, keep_forearm_off_object): the "
        "law asked to take the arm further towards it",
    )
    goal_px: Corners2 | None = Field(
        None,
        description="s* as the law used it this step, paired with the hand's corners: row i is "
        "where hand corner i is driven (px; from memory while the hand hides the target); "
        "None when the twist is not the law's",
    )

    @property
    def servoing(self) -> bool:
        """A twist of the control law, whose ``error_px_rms`` is the image error: not a hold,
        and not an acquisition's move (valid, its ``hold_reason`` saying so, and no image
        error to give: its 0 is no measurement)."""
        return self.valid and not self.hold_reason


class JointVelocityCommand(Message):
    """Joint velocity set-points for joint_1..joint_6 (rad/s)."""

    header: Header
    velocity_rad_s: JointRates
    reason: Literal["track", "hold", "deadman"] = "track"


class SimTruth(Message):
    """Simulator ground truth, for evaluation only: no perception or control may use it."""

    header: Header
    hand_marker_pose: Pose16 = Field(description="row-major 4×4, base frame")
    target_marker_pose: Pose16
    hand_corners_px: Corners2
    target_corners_px: Corners2
    ee_position_m: Vec3
    joint_position_rad: Joints
    arm_contact_n: float = Field(
        0.0, ge=0.0, le=1e7, description="summed normal force of the arm's contacts (N)"
    )
    arm_contact_with: list[str] = Field(
        default_factory=list, max_length=8, description="what the arm touches: object, table..."
    )


class AppliedCommand(Message):
    """When the sim received one joint command and when its motors started following it."""

    frame_seq: int = Field(ge=-1, description="the command's header.frame_seq")
    send_time_s: float = Field(ge=0.0, le=1e11, description="the command's header.send_time_s")
    recv_time_s: float = Field(ge=0.0, le=1e11, description="wall clock, Unix s")
    applied_time_s: float = Field(ge=0.0, le=1e11, description="wall clock, Unix s")
    velocity_rad_s: JointRates | None = Field(
        None, description="the command's joint velocities, before the motors' own limit"
    )


class SimTiming(Message):
    """The sim's own timing of camera frame ``header.frame_seq``, and the joint commands it
    applied after that frame went out (the command that answered it among them): with the other
    services' headers this gives every stage of the loop, frame captured → command applied
    (``umay bench``). Published when the next frame starts, before its render: off the frame's
    path, and complete.

    Wall-clock times are Unix seconds. ``capture_time_s``: the images exist (render and sensor
    model done); ``frame_send_time_s``: the colour frame's ``header.send_time_s``."""

    header: Header
    render_start_s: float = Field(ge=0.0, le=1e11)
    capture_time_s: float = Field(ge=0.0, le=1e11)
    frame_send_time_s: float = Field(ge=0.0, le=1e11)
    with_depth: bool
    dropped_frames: int = Field(0, ge=0, description="camera ticks missed so far (realtime)")
    resends: int = Field(0, ge=0, description="lockstep re-publications so far")
    applied: Annotated[list[AppliedCommand], Field(max_length=64)] = []


# One published message's stamps: (header.frame_seq, header.recv_time_s, header.send_time_s).
Stamp = tuple[int, float, float]


class PublishedStamps(Message):
    """Answer of ``<prefix>/<service>/stamps``: the header stamps of the last messages the
    service published, per key (relative to the prefix), oldest first. ``umay bench`` asks for
    them after a run to split each frame into stages, instead of subscribing to every hop while
    the loop runs (an extra subscriber is one more send on each publisher's path and one more
    process woken per message)."""

    service: str
    stamps: dict[str, list[Stamp]] = {}


class TopicStats(Message):
    """Traffic on one key as seen by one service."""

    count: int = Field(ge=0)
    rate_hz: float = Field(ge=0.0, description="over the last few seconds")
    age_s: float | None = Field(None, description="since the last message; None: never")
    dropped: int = Field(0, ge=0, description="replaced by a newer one before being processed")
    by_ref: int = Field(
        0, ge=0, description="camera frames by reference (a view of the sim's shared-memory ring)"
    )
    by_copy: int = Field(0, ge=0, description="camera frames whole, by copy")
    fetched: int = Field(
        0, ge=0, description="of by_copy, asked from the publisher: its ring was unreachable"
    )


class StatusFields(BaseModel):
    """A service's own status fields (:attr:`ServiceStatus.fields`). Each service describes
    its own in a subclass, every field with its meaning and unit: the service builds one per
    status answer (an unknown or missing field, or a value pydantic cannot convert, fails
    there, not in a reader), and
    docs/operations.md renders them all (``umay docs``). On the wire they stay a plain map, so
    that a tool reads any service's fields without importing the service."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class ServiceStatus(Message):
    """Answer of ``<prefix>/<service>/status``."""

    service: str
    pid: int
    host: str
    uptime_s: float
    state: Literal["starting", "running", "degraded", "stopping"]
    degraded_reason: str = ""
    received: dict[str, TopicStats] = {}
    published: dict[str, TopicStats] = {}
    rejected: int = 0
    last_rejection: str = ""
    processing_ms_p50: float | None = None
    processing_ms_p99: float | None = None
    # Seconds the service has been in its current step (an event, or its idle work) since it
    # last waited (0 while it waits; None before it first does): what tells a stuck service
    # from an idle one.
    loop_busy_s: float | None = None
    fields: dict[str, Any] = {}
