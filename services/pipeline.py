"""The whole loop in one process: the four services' pure steps composed, one camera frame at a
time, exactly as the distributed lockstep run chains them over Zenoh.

Not a service: it imports the services' pure modules (never their node shells), and no service
imports it. Per frame, as in lockstep: the sim renders frame k (a depth image with it when the
schedule says so), vision measures it, the controller turns the features and the frame's joint
state into a twist, actuation turns that into a joint command under its acceleration limit,
the sim applies it through the motors' own limit for one camera period of physics. Values go
from step to step through the same wire messages the services exchange (``Features``,
``EndEffectorTwist``), so a lockstep run and this pipeline compute the same numbers.

The sim's ground truth of each frame is taken for evaluation only (``FrameRecord.truth``);
nothing of it flows into vision or control. Users: ``umay run --inprocess``
(deploy/launch/run_inprocess.py) and the in-process baseline of ``umay bench``
(deploy/bench/inprocess.py), which times the stages from ``FrameRecord.stage_s``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from types import TracebackType

import numpy as np

from common.config import Scenario, substeps_per_frame
from common.kinematics import FloatArray
from common.messages import EndEffectorTwist, Features, Header, SimTruth
from services.actuation.limiter import ActuationStep, LimiterState, actuation_step
from services.controller.ibvs import ControlOutput, IbvsController
from services.controller.step import control_step, twist_message
from services.sim.motors import motor_velocities
from services.sim.schedule import DepthSchedule
from services.sim.truth import truth_message
from services.sim.world import World
from services.vision.step import VisionStep, depth_image, vision_step
from services.vision.tracking import TrackerState

# The stages of one frame that FrameRecord.stage_s times (wall clock, seconds): the render, each
# service's step (with building its wire message), and applying the command to the motors.
STAGES: tuple[str, ...] = ("render", "vision", "controller", "actuation", "apply")


@dataclass(frozen=True)
class FrameRecord:
    """One camera frame through the loop."""

    frame_seq: int
    sim_time_s: float
    q_rad: FloatArray  # joint state of the frame (what the encoders report)
    qdot_rad_s: FloatArray
    rgb: np.ndarray
    depth_m: np.ndarray | None  # the depth image taken with this frame, if one was
    depth_frame_seq: int  # the frame that took the newest depth image (-1: none yet)
    features: Features  # vision's output, as published
    control: ControlOutput  # the controller's
    twist: EndEffectorTwist  # ... as published
    actuation: ActuationStep  # actuation's (its ``velocity_rad_s`` is the joint command)
    motors_rad_s: FloatArray  # what the motors follow: the command within their own limit
    truth: SimTruth | None  # evaluation only (None: not asked for)
    stage_s: dict[str, float]  # wall time of each of STAGES


class Pipeline:
    """The loop's state, all of it, as data: the sim's world and depth schedule, the vision
    tracker, the controller, the actuation limiter. ``truth``: also take each frame's ground
    truth (for judging a run; the bench does without). Close it (or use ``with``): it owns a
    pybullet client and maybe an OpenGL context."""

    def __init__(self, scenario: Scenario, truth: bool = True) -> None:
        self.scenario = scenario
        self.take_truth = truth
        camera = scenario.camera
        self.world = World(scenario)
        self.substeps = substeps_per_frame(camera.rgb_hz, self.world.physics_dt_s)
        self.camera_period_s = scenario.frame_period_s  # the acceleration limit's longest gap
        self.schedule = DepthSchedule.of(camera, scenario.frame_period_s)
        self.depth: tuple[np.ndarray, float] | None = None  # newest depth image, its sim time
        self.tracker = TrackerState()
        self.controller = IbvsController.of(scenario)
        self.limiter = LimiterState()
        self.frame_seq = 0
        self.motor_clamps = 0  # commands beyond the motors' own speed limit

    def close(self) -> None:
        self.world.close()

    def __enter__(self) -> Pipeline:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def step(
        self, after_vision: Callable[[Callable[[], VisionStep]], None] | None = None
    ) -> FrameRecord:
        """Frame ``frame_seq``: render, vision, controller, actuation, apply, then one camera
        period of physics. ``after_vision`` is called with vision's step bound to this frame's
        inputs (calling it measures the frame again, state unchanged) between the vision and
        the controller stages, outside both (the bench times a warm second call so)."""
        clock = time.perf_counter
        world, scenario = self.world, self.scenario
        seq = self.frame_seq
        world.update_scene()
        t = world.sim_time_s
        q, qdot = world.joint_state()
        header = Header(seq=seq, sim_time_s=t, send_time_s=0.0, frame_seq=seq)
        r0 = clock()
        rgb, depth_m = world.render(self.schedule.due(t))
        r1 = clock()  # images ready
        if depth_m is not None:
            self.schedule = self.schedule.taken(t, seq)
            self.depth = (depth_m, t)
        truth = truth_message(world.truth(), header, q) if self.take_truth else None
        # vision
        v0 = clock()
        depth = None
        if self.depth is not None:
            depth = depth_image(self.depth[0], world.depth_intrinsics, self.depth[1], t)
        measure = partial(
            vision_step,
            rgb,
            world.intrinsics,
            depth,
            scenario.vision,
            scenario.marker.size_m,
            self.tracker,
            t,
            scenario.marker.orientation_cue,
        )
        seen = measure()
        features = seen.features(header, world.intrinsics)
        v1 = clock()
        if after_vision is not None:
            after_vision(measure)
        self.tracker = seen.tracker
        # controller
        c0 = clock()
        out = control_step(self.controller, features, q)
        twist = twist_message(out, header, self.controller.config.mode.value)
        c1 = clock()
        # actuation
        acted = actuation_step(
            scenario.actuation,
            self.limiter,
            np.array(twist.linear_m_s + twist.angular_rad_s),
            twist.valid,
            q,
            t,
            self.camera_period_s,
        )
        self.limiter = acted.state
        a1 = clock()
        # apply: the sim takes the command as the wire carries it, through the motors' limit
        motors, clamped = motor_velocities(acted.velocity_rad_s.tolist())
        self.motor_clamps += clamped
        world.set_joint_velocities(motors)
        p1 = clock()
        world.step(self.substeps)
        self.frame_seq += 1
        return FrameRecord(
            frame_seq=seq,
            sim_time_s=t,
            q_rad=q,
            qdot_rad_s=qdot,
            rgb=rgb,
            depth_m=depth_m,
            depth_frame_seq=self.schedule.depth_frame_seq,
            features=features,
            control=out,
            twist=twist,
            actuation=acted,
            motors_rad_s=motors,
            truth=truth,
            stage_s={
                "render": r1 - r0,
                "vision": v1 - v0,
                "controller": c1 - c0,
                "actuation": a1 - c1,
                "apply": p1 - a1,
            },
        )
