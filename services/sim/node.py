"""Sim service: steps the pybullet world, publishes RGB-D frames, joint states and (for
evaluation only) ground truth; applies joint velocity commands.

Clock modes:
- lockstep: render frame k, publish it, wait for the command derived from frame k, apply it for
  one camera period, repeat. Deterministic and independent of machine speed. A frame whose
  command does not come back within ``sim.lockstep_resend_s`` is published again (same seq).
- realtime: physics follows the wall clock; a frame is rendered at each camera tick, and ticks
  missed while rendering are counted as dropped.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from common import kinematics as kin
from common.config import ClockMode
from common.keys import SERVICES
from common.messages import ImageData, JointState, JointVelocityCommand, RgbdFrame, SimTruth
from common.runtime import ServiceContext
from common.transport import Node, alive_services
from services.sim.world import World

log = logging.getLogger("umay.sim")


class SimService:
    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        self.scenario = ctx.scenario
        self.world = World(ctx.scenario)
        self.period_s = 1.0 / ctx.scenario.camera.rate_hz
        self.substeps = max(1, round(self.period_s / self.world.physics_dt_s))
        self.frame_seq = 0
        self.dropped_frames = 0
        self.render_ms = 0.0
        self.started_s = time.monotonic()
        self.node = Node("sim", ctx.keys, ctx.session, self.status_fields)
        keys = ctx.keys
        self.pub_frame = self.node.publisher(keys.rgbd)
        self.pub_joints = self.node.publisher(keys.joint_state)
        self.pub_truth = self.node.publisher(keys.truth)
        self.node.subscribe(keys.joint_command, JointVelocityCommand)
        self.last_command = np.zeros(kin.N_JOINTS)
        self.last_command_s: float | None = None  # wall clock (monotonic)
        self.watchdog_stops = 0
        self.motor_clamps = 0  # commands beyond the motors' own speed limit

    def status_fields(self) -> dict:
        return {
            "clock": self.scenario.run.clock.value,
            "sim_time_s": round(self.world.sim_time_s, 4),
            "frame_seq": self.frame_seq,
            "render_ms": round(self.render_ms, 2),
            "dropped_frames": self.dropped_frames,
            "watchdog_stops": self.watchdog_stops,
            "motor_clamps": self.motor_clamps,
            "real_time_factor": round(
                self.world.sim_time_s / max(time.monotonic() - self.started_s, 1e-9), 3
            ),
        }

    # --- publishing one camera frame ----------------------------------------------------
    def publish_frame(self) -> None:
        started_publish = time.perf_counter()
        seq, t = self.frame_seq, self.world.sim_time_s
        q, qdot = self.world.joint_state()
        started = time.perf_counter()
        rgb, depth_m = self.world.render()
        self.render_ms = 1000.0 * (time.perf_counter() - started)
        truth = self.world.truth()
        header = self.node.header(t, seq)
        # Joint state first, so a consumer has it when the frame's features arrive.
        self.pub_joints.put(
            JointState(header=header, position_rad=q.tolist(), velocity_rad_s=qdot.tolist())
        )
        self.pub_truth.put(
            SimTruth(
                header=header,
                hand_marker_pose=truth.hand_marker_pose.reshape(-1).tolist(),
                target_marker_pose=truth.target_marker_pose.reshape(-1).tolist(),
                hand_corners_px=truth.hand_corners_px.tolist(),
                target_corners_px=truth.target_corners_px.tolist(),
                ee_position_m=truth.ee_position_m.tolist(),
                joint_position_rad=q.tolist(),
            )
        )
        self.pub_frame.put(
            RgbdFrame(
                header=header,
                intrinsics=self.world.intrinsics,
                rgb=ImageData.from_array(rgb),
                depth_m=ImageData.from_array(depth_m),
            )
        )
        self.node.processing.add(1000.0 * (time.perf_counter() - started_publish))

    def apply(self, command: JointVelocityCommand) -> None:
        # The motors' own limit, whatever the command says.
        limit = kin.JOINT_VELOCITY_LIMIT_RAD_S
        wanted = np.array(command.velocity_rad_s)
        self.motor_clamps += bool(np.any(np.abs(wanted) > limit))
        self.last_command = np.clip(wanted, -limit, limit)
        self.last_command_s = time.monotonic()
        self.world.set_joint_velocities(self.last_command)

    def check_watchdog(self) -> None:
        """Second line of defence behind the actuation deadman: no command, no motion."""
        if self.last_command_s is None or not np.any(self.last_command):
            return
        if time.monotonic() - self.last_command_s > self.scenario.sim.command_watchdog_s:
            self.last_command = np.zeros(kin.N_JOINTS)
            self.world.set_joint_velocities(self.last_command)
            self.watchdog_stops += 1
            log.warning(
                "no joint command for %.2f s: motors stopped", self.scenario.sim.command_watchdog_s
            )

    # --- clock modes --------------------------------------------------------------------
    def wait_for_peers(self, timeout_s: float = 20.0) -> None:
        """Before the first lockstep frame: wait until the other services announce themselves."""
        deadline = time.monotonic() + timeout_s
        others = set(SERVICES) - {"sim"}
        while not self.ctx.stop.is_set() and time.monotonic() < deadline:
            if others <= alive_services(self.ctx.session, self.ctx.keys, 0.5):
                time.sleep(0.2)  # let their subscriptions propagate too
                return
            time.sleep(0.1)
        log.warning("not all services announced themselves; starting anyway")

    def run_lockstep(self) -> None:
        self.wait_for_peers()
        resend_s = self.scenario.sim.lockstep_resend_s
        while not self.ctx.stop.is_set():
            self.publish_frame()
            sent = time.monotonic()
            while not self.ctx.stop.is_set():
                event = self.node.next_event(0.05)
                if event is not None and event[1].header.frame_seq == self.frame_seq:
                    self.apply(event[1])
                    break
                if time.monotonic() - sent > resend_s:
                    log.info("no command for frame %d yet; publishing it again", self.frame_seq)
                    self.publish_frame()
                    sent = time.monotonic()
            else:
                return
            self.world.step(self.substeps)
            self.frame_seq += 1

    def run_realtime(self) -> None:
        started = time.monotonic()
        next_frame_s = 0.0
        while not self.ctx.stop.is_set():
            event = self.node.next_event(0.0)
            while event is not None:  # apply the newest command
                self.apply(event[1])
                event = self.node.next_event(0.0)
            self.check_watchdog()
            wall_s = time.monotonic() - started
            behind = int((wall_s - self.world.sim_time_s) / self.world.physics_dt_s)
            if behind > 0:
                self.world.step(behind)
            if self.world.sim_time_s >= next_frame_s:
                missed = math.floor((self.world.sim_time_s - next_frame_s) / self.period_s)
                self.dropped_frames += missed
                self.publish_frame()
                self.frame_seq += 1
                next_frame_s += (missed + 1) * self.period_s
            # Sleep until the next physics step is due (rendering may already have overrun it).
            elapsed_s = time.monotonic() - started - wall_s
            self.ctx.stop.wait(max(0.0, self.world.physics_dt_s - elapsed_s))

    def run(self) -> None:
        self.node.ready()
        try:
            if self.scenario.run.clock is ClockMode.LOCKSTEP:
                self.run_lockstep()
            else:
                self.run_realtime()
        finally:
            self.world.set_joint_velocities(np.zeros(kin.N_JOINTS))
            self.node.close()
            self.world.close()


def main(argv: list[str] | None = None) -> int:
    ctx = ServiceContext("sim", argv)
    SimService(ctx).run()
    return 0
