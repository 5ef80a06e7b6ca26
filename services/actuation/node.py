"""Actuation service: twist + joint encoders → joint velocity commands, limits, deadman.

The deadman runs on the wall clock: without a fresh valid twist for ``deadman_timeout_s`` it
commands zero velocity (again every ``deadman_timeout_s`` while it lasts).

Stops (hold, deadman) are immediate; the acceleration limit shapes tracking motion only, and
the time base for it is the sim time between consecutive commands, so after a stop the arm
starts again from rest with a ramp. In lockstep the sim applies only the command that answers
its frame (and physics waits for it), so there a deadman stop never reaches the motors and must
not reset the limiter either: otherwise a slow render would change the trajectory and two
lockstep runs would differ. The step itself is :func:`services.actuation.limiter.actuation_step`
(pure, with the limiter's state as data); this shell pairs, counts, runs the deadman, publishes.
"""

from __future__ import annotations

import time

import numpy as np

from common import kinematics as kin
from common.config import ClockMode
from common.messages import EndEffectorTwist, JointState, JointVelocityCommand
from common.node import Node
from common.pairing import FramePairer
from common.runs import RunWatch
from common.runtime import ServiceContext
from services.actuation.inverse import Clamps, deadman_expired
from services.actuation.limiter import LimiterState, actuation_step
from services.actuation.status import ActuationStatus


class ActuationService:
    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        self.config = ctx.scenario.actuation
        self.lockstep = ctx.scenario.run.clock == ClockMode.LOCKSTEP
        self.camera_period_s = ctx.scenario.frame_period_s  # the acceleration's longest gap
        self.node = Node("actuation", ctx.keys, ctx.session, self.status_fields, self.degraded)
        self.pub = self.node.publisher(ctx.keys.joint_command)
        self.node.subscribe(ctx.keys.twist, EndEffectorTwist)
        self.node.subscribe(ctx.keys.joint_state, JointState)
        self.runs = RunWatch()  # the sim's run the inputs come from (common.runs)
        self.last_valid_twist_s: float | None = None
        self.last_deadman_s = 0.0
        self.deadman_stops = 0
        self.saturated: list[int] = []
        self.manipulability = float("nan")
        self.new_run()
        # Every stop and clamp, counted (commands, not joints).
        self.counts = {
            "hold_stops": 0,
            "position_limit_clamps": 0,
            "velocity_clamps": 0,
            "acceleration_clamps": 0,
            "nonfinite_guards": 0,
            "damped_commands": 0,
        }

    def new_run(self) -> None:
        """A restarted sim starts its run again from frame 0 with the motors at rest: no input
        waits for a partner of the run before, no answer is kept for a resend, and the
        acceleration limit ramps from rest (sim time began again: the last command's time
        base is gone)."""
        self.pairer: FramePairer[EndEffectorTwist, JointState] = FramePairer()
        self.last_output: JointVelocityCommand | None = None
        self.limiter = LimiterState()  # the command the motors follow now
        self.sim_time_s = 0.0  # the newest input's sim time: a deadman stop's (it has none)

    def deadman_active(self) -> bool:
        return deadman_expired(
            time.monotonic(), self.last_valid_twist_s, self.config.deadman_timeout_s
        )

    def stopped_by_deadman(self) -> bool:
        """The deadman holds the motors at zero: a twist came once, none fresh since. Before
        the first twist the motors are simply at rest: neither a stop nor a degradation."""
        return self.last_valid_twist_s is not None and self.deadman_active()

    def status_fields(self) -> ActuationStatus:
        return ActuationStatus(
            deadman=self.stopped_by_deadman(),
            deadman_stops=self.deadman_stops,
            **self.counts,
            saturated_joints=self.saturated,
            manipulability=self.manipulability,
        )

    def degraded(self) -> str:
        stopped = self.stopped_by_deadman()
        return "deadman: no fresh twist, motors commanded to zero" if stopped else ""

    def publish(self, velocity: np.ndarray, reason: str, sim_time_s: float, frame_seq: int) -> None:
        command = JointVelocityCommand(
            header=self.node.header(sim_time_s, frame_seq, run=self.runs.current or 0),
            velocity_rad_s=velocity.tolist(),
            reason=reason,  # type: ignore[arg-type]
        )
        if frame_seq >= 0:
            self.last_output = command
        self.pub.put(command)

    def on_pair(self, twist: EndEffectorTwist, joints: JointState) -> None:
        t, seq = twist.header.sim_time_s, twist.header.frame_seq
        self.sim_time_s = max(self.sim_time_s, t)
        if twist.valid:
            if not self.lockstep and self.deadman_active():
                # No fresh twist for the deadman's time: the motors were stopped, by the
                # deadman or, if it could not send (this process frozen), by the sim's
                # watchdog. Ramp up from rest, not from the command before the gap: over one
                # camera period, as from a frame's command (with no time base the ramp allowed
                # nothing, and twists that came that far apart never moved the arm).
                self.limiter = LimiterState.at_rest_since(t - self.camera_period_s)
            self.last_valid_twist_s = time.monotonic()
        step = actuation_step(
            self.config,
            self.limiter,
            np.array(twist.linear_m_s + twist.angular_rad_s),
            twist.valid,
            np.array(joints.position_rad),
            t,
            self.camera_period_s,
        )
        self.limiter = step.state  # what the motors will follow, as the pure step has it
        if step.joint is None:
            self.counts["hold_stops"] += 1
        else:
            self.saturated, self.manipulability = step.joint.saturated, step.joint.manipulability
            self.count(step.joint.clamps, step.joint.damping)
        self.publish(step.velocity_rad_s, step.reason, t, seq)

    def count(self, clamps: Clamps, damping: float) -> None:
        self.counts["position_limit_clamps"] += bool(clamps.position)
        self.counts["velocity_clamps"] += bool(clamps.velocity)
        self.counts["acceleration_clamps"] += clamps.acceleration
        self.counts["nonfinite_guards"] += clamps.nonfinite
        self.counts["damped_commands"] += damping > 0.0

    def check_deadman(self) -> None:
        now = time.monotonic()
        timeout = self.config.deadman_timeout_s
        if self.last_valid_twist_s is None:
            return  # nothing commanded yet: the motors are at rest
        if deadman_expired(now, self.last_valid_twist_s, timeout) and (
            now - self.last_deadman_s > timeout
        ):
            self.last_deadman_s = now
            self.deadman_stops += 1
            self.publish(np.zeros(kin.N_JOINTS), "deadman", self.sim_time_s, -1)

    def on_event(self, key: str, msg: EndEffectorTwist | JointState) -> None:
        if not self.runs.admit(msg.header.run, self.new_run):
            self.node.count_dropped(key)  # sent before the sim restarted
            return
        if msg.header.frame_seq == self.pairer.last_paired and self.last_output is not None:
            self.pub.put(self.last_output)  # a re-published frame: same answer again
            return
        pair = self.pairer.add(key == self.ctx.keys.twist, msg.header.frame_seq, msg)
        if pair is not None:
            self.on_pair(*pair)

    def run(self) -> None:
        self.node.spin(self.ctx.stop, self.on_event, timeout_s=0.02, on_idle=self.check_deadman)


def main(argv: list[str] | None = None) -> int:
    with ServiceContext("actuation", argv) as ctx:  # its session closed however it ends
        ActuationService(ctx).run()
    return 0
