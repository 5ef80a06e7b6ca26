"""One experiment: the ``Scenario`` model, its own small tables (``[robot]``, ``[target]``,
``[marker]``, ``[run]``) and the checks that span several tables (each table's own checks are in
its module)."""

from __future__ import annotations

import math
import re
from enum import StrEnum

import numpy as np
from pydantic import Field, field_validator, model_validator

from common.config.actuation import ActuationConfig
from common.config.base import Joints6, Strict, Vec3
from common.config.camera import CameraConfig
from common.config.controller import ControllerConfig
from common.config.events import MAX_TARGET_SPEED_M_S, Event, EventAction
from common.config.sim import SimConfig
from common.config.supervisor import SupervisorConfig
from common.config.vision import VisionConfig
from common.kinematics import (
    HAND_THICKNESS_M,
    JOINT_VELOCITY_LIMIT_RAD_S,
    MARKER_THICKNESS_M,
    POSITION_LIMIT_ZONE_RAD,
)


class ClockMode(StrEnum):
    """How simulated time advances."""

    LOCKSTEP = "lockstep"  # one camera period per command: deterministic, speed-independent
    REALTIME = "realtime"  # physics at wall-clock rate, frames dropped when rendering lags


class RobotConfig(Strict):
    q0: Joints6 = Field(description="initial joint angles (rad), joint_1..joint_6")


OBJECT_SIDE_PER_MARKER = 1.25  # the object's top face, in marker sides, unless given


class TargetConfig(Strict):
    position: Vec3 = Field(description="red marker centre in the arm base frame (m)")
    yaw: float = Field(0.0, ge=-math.pi, le=math.pi, description="about the vertical (rad)")
    approach_height_m: float = Field(
        0.03,
        ge=0.0,
        le=0.2,
        description="the hand's marker stops this far above the red one, along its normal (m)",
    )
    object_side_m: float | None = Field(
        None,
        gt=0.0,
        le=0.5,
        description="side of the object's square top face, centred under the red marker (m; "
        "default 1.25 × marker.size_m): the sim builds the object so, and the controller is "
        "given it as the object's model (as vision is given the marker's size) to keep the "
        "forearm off it",
    )


class MarkerConfig(Strict):
    size_m: float = Field(0.06, gt=0.01, le=0.2, description="side of both square markers (m)")
    orientation_cue: bool = Field(
        False,
        description="each marker carries a small blue square inside it near its corner 0, so "
        "vision labels the corners physically and a hand turned up to 180° about the optical "
        "axis is seen as such (a plain square looks the same turned by 90°); the controller "
        "then pairs hand corner i with target corner i. Off: the thesis's plain squares",
    )


class RunConfig(Strict):
    clock: ClockMode = Field(
        ClockMode.LOCKSTEP,
        description="lockstep: one camera period per command, deterministic; realtime: "
        "physics at the wall clock's rate, frames dropped when rendering lags",
    )
    timeout_s: float = Field(30.0, gt=0.0, le=3600.0, description="simulated seconds")


DEADMAN_FRAMES = 1.5  # the deadman's time, in camera frames, must exceed this


FRAME_RATE_TOLERANCE = 0.25  # the camera's rate in whole physics steps, this near rgb_hz


class Scenario(Strict):
    name: str = Field(
        "default",
        description="the scenario's name in results and recordings (letters, digits, _ . -: it "
        "names folders)",
    )
    robot: RobotConfig
    target: TargetConfig
    marker: MarkerConfig = MarkerConfig()
    camera: CameraConfig
    vision: VisionConfig = VisionConfig()
    controller: ControllerConfig = ControllerConfig()
    actuation: ActuationConfig = ActuationConfig()
    sim: SimConfig = SimConfig()
    run: RunConfig = RunConfig()
    supervisor: SupervisorConfig = SupervisorConfig()
    events: list[Event] = Field(
        default_factory=list,
        max_length=100,
        description="a timeline the sim acts on (`[[events]]`, below); a run is not judged "
        "converged before the last event ends",
    )

    @model_validator(mode="after")
    def _object_holds_its_marker(self) -> Scenario:
        if self.object_side_m < self.marker.size_m:
            raise ValueError(
                f"target.object_side_m ({self.object_side_m}) below marker.size_m "
                f"({self.marker.size_m}): the red marker lies on the object's top face"
            )
        return self

    @model_validator(mode="after")
    def _deadman_before_watchdog(self) -> Scenario:
        deadman, watchdog = self.actuation.deadman_timeout_s, self.sim.command_watchdog_s
        if deadman >= watchdog:
            raise ValueError(
                f"actuation.deadman_timeout_s ({deadman}) not below sim.command_watchdog_s "
                f"({watchdog}): the deadman is the first stop, the sim's watchdog the second, "
                "and the stop must have time to reach the motors before the watchdog acts"
            )
        return self

    @field_validator("name")
    @classmethod
    def _a_folder_name(cls, name: str) -> str:
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", name) or set(name) == {"."}:
            raise ValueError(f"{name!r}: letters, digits, _ . - only (it names a folder)")
        return name

    @model_validator(mode="after")
    def _deadman_longer_than_a_frame(self) -> Scenario:
        # In realtime twists come once a camera frame: a deadman as short would stop the arm
        # between any two of them, and each twist would find it stopped and ramp it up from
        # rest again, so the arm never moves. (In lockstep the motors follow each frame's
        # command whatever the deadman sends between frames: tests use that.)
        if self.run.clock is not ClockMode.REALTIME:
            return self
        deadman, frame_s = self.actuation.deadman_timeout_s, self.frame_period_s
        if deadman <= DEADMAN_FRAMES * frame_s:
            raise ValueError(
                f"actuation.deadman_timeout_s ({deadman}) not above {DEADMAN_FRAMES:g} camera "
                f"frames ({DEADMAN_FRAMES * frame_s:.3f} s at camera.rgb_hz "
                f"{self.camera.rgb_hz:g}): in realtime it would stop the arm between two twists"
            )
        return self

    @model_validator(mode="after")
    def _goal_above_the_clearance(self) -> Scenario:
        # The hand box lies under its marker: with the box kept above the object's top face,
        # a goal lower than the box's thickness and the clearance is one the hand never reaches.
        if not self.controller.keep_above_target:
            return self
        lowest = HAND_THICKNESS_M + MARKER_THICKNESS_M + self.controller.hand_clearance_m
        if self.target.approach_height_m < lowest:
            raise ValueError(
                f"target.approach_height_m ({self.target.approach_height_m}) below {lowest:.4f} "
                "m, the hand box's thickness under its marker and controller.hand_clearance_m: "
                "the clearance keeps the hand from its goal (or set "
                "controller.keep_above_target = false)"
            )
        return self

    @model_validator(mode="after")
    def _moves_together_within_the_speed_limit(self) -> Scenario:
        # Moves that overlap add up (services/sim/events.py): their sum has the one's limit.
        moves = [(i, e) for i, e in enumerate(self.events) if e.action is EventAction.MOVE_TARGET]
        for i, started in moves:
            t = started.at_s  # the sum only changes where a move starts or ends
            together = [e for _, e in moves if e.at_s <= t < e.end_s]
            speed = float(np.linalg.norm(np.sum([e.velocity_m_s for e in together], axis=0)))
            if speed > MAX_TARGET_SPEED_M_S:
                raise ValueError(
                    f"events[{i}]: with the moves it overlaps the object slides at {speed:.3f} "
                    f"m/s at {t:g} s, above {MAX_TARGET_SPEED_M_S:g} m/s"
                )
        return self

    @model_validator(mode="after")
    def _events_within_the_run(self) -> Scenario:
        # A run is judged converged only once the last event is over.
        if self.events_end_s > self.run.timeout_s:
            last = int(np.argmax([e.end_s for e in self.events]))
            raise ValueError(
                f"events[{last}] ends at {self.events_end_s:g} s, after run.timeout_s "
                f"({self.run.timeout_s:g}): a run is judged only once its events are over"
            )
        return self

    @model_validator(mode="after")
    def _frames_near_the_rate_asked(self) -> Scenario:
        # A frame lasts whole physics steps: the rate the camera gets is physics_hz over their
        # number, which for a rate near or above physics_hz is far from the one asked.
        got_hz = 1.0 / self.frame_period_s
        if abs(got_hz - self.camera.rgb_hz) > FRAME_RATE_TOLERANCE * self.camera.rgb_hz:
            raise ValueError(
                f"camera.rgb_hz ({self.camera.rgb_hz:g}) at sim.physics_hz "
                f"({self.sim.physics_hz:g}): a frame lasts whole physics steps, which makes "
                f"{got_hz:.4g} frames/s; choose a rate that divides the physics rate"
            )
        return self

    @model_validator(mode="after")
    def _a_frame_shorter_than_the_slow_down_zone(self) -> Scenario:
        # A joint command is followed for one camera frame (lockstep: whole physics steps), and
        # actuation bounds the speed towards a limit by the angle at the frame's start: a frame
        # crossing the whole slow-down zone at full speed could carry a joint past its limit.
        crossing_s = POSITION_LIMIT_ZONE_RAD / float(np.max(JOINT_VELOCITY_LIMIT_RAD_S))
        if self.frame_period_s >= crossing_s:
            raise ValueError(
                f"camera.rgb_hz ({self.camera.rgb_hz}) at sim.physics_hz "
                f"({self.sim.physics_hz}) makes a camera frame of {self.frame_period_s:.4f} s "
                f"(whole physics steps), not below the {crossing_s:.4f} s a joint takes to cross "
                "its slow-down zone at full speed: a joint could pass its limit within a frame"
            )
        return self

    @property
    def object_side_m(self) -> float:
        """The object's top face side (m): ``target.object_side_m``, else 1.25 markers."""
        side = self.target.object_side_m
        return OBJECT_SIDE_PER_MARKER * self.marker.size_m if side is None else side

    @property
    def frame_period_s(self) -> float:
        """The sim time between two camera frames: the camera period in whole physics steps
        (:func:`substeps_per_frame`), as the sim advances its clock."""
        physics_dt_s = 1.0 / self.sim.physics_hz
        return substeps_per_frame(self.camera.rgb_hz, physics_dt_s) * physics_dt_s

    @property
    def events_end_s(self) -> float:
        """When the last scheduled event is over (0 without events): a run is not judged
        converged before it."""
        return max((e.end_s for e in self.events), default=0.0)


def substeps_per_frame(rgb_hz: float, physics_dt_s: float) -> int:
    """Physics steps in one camera period (at least one)."""
    return max(1, round(1.0 / rgb_hz / physics_dt_s))
