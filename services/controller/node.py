"""Controller service: features + joint encoders → end-effector twist (eye-to-hand IBVS).

It uses only what the camera and the joint encoders give, plus the *assumed* camera pose (the
scenario's camera mount, i.e. the calibration); never the simulator's ground truth. The step
itself is :func:`services.controller.step.control_step` (pure); this shell pairs and publishes.
"""

from __future__ import annotations

import logging

import numpy as np

from common.messages import EndEffectorTwist, Features, JointState
from common.node import Node
from common.pairing import FramePairer
from common.runs import RunWatch
from common.runtime import ServiceContext
from services.controller.ibvs import IbvsController, describe_hold, is_stuck
from services.controller.progress import Progress, describe_stall
from services.controller.stability import unstable_goal_consequence
from services.controller.status import ControllerStatus
from services.controller.step import control_step, twist_message

log = logging.getLogger("umay.controller")


class ControllerService:
    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        self.node = Node("controller", ctx.keys, ctx.session, self.status_fields, self.degraded)
        self.pub = self.node.publisher(ctx.keys.twist)
        self.node.subscribe(ctx.keys.features, Features)
        self.node.subscribe(ctx.keys.joint_state, JointState)
        self.runs = RunWatch()  # the sim's run the inputs come from (common.runs)
        self.clearance_lifts = 0  # twists corrected to keep the arm off the object
        self.new_run()

    def new_run(self) -> None:
        """Servo afresh: a restarted sim starts its run again from frame 0, the arm in its
        start posture, so nothing the controller kept from the run before holds (its goal
        memories, pairing, frozen matrix, progress, the inputs waiting for a partner)."""
        scenario = self.ctx.scenario
        self.controller = IbvsController.of(scenario)
        self.pairer: FramePairer[Features, JointState] = FramePairer()
        self.error_px = float("nan")
        self.converged = False
        self.holding = False
        self.hold_reason = ""
        self.phase = "servoing"  # servoing / acquiring / holding (ControlOutput.phase)
        self.hold_since_s: float | None = None  # sim time the current hold began
        self.sim_time_s = 0.0  # of the last frame stepped
        self.target_speed_m_s = 0.0  # estimated; set by the event loop, read by status queries
        self.last_output: EndEffectorTwist | None = None
        self.target_remembered = False
        self.lifted = False  # the last twist was
        self.hand_predicted = False  # the last twist servoed on the hand carried by the encoders
        self.progress = Progress()  # whether servoing still brings the error down

    def status_fields(self) -> ControllerStatus:
        since = self.hold_since_s
        return ControllerStatus(
            mode=self.controller.config.mode.value,
            error_px_rms=self.error_px,
            converged=self.converged,
            holding=self.holding,
            hold_reason=self.hold_reason,
            phase=self.phase,
            hold_since_s=since,
            holding_for_s=None if since is None else self.sim_time_s - since,
            stuck=self.stuck(),
            error_best_px=self.progress.best_px,
            stalled_for_s=self.progress.stalled_for_s(self.sim_time_s),
            stalled=self.stalled(),
            target_remembered=self.target_remembered,
            target_predicted=self.controller.target_memory.predicted,
            target_speed_m_s=self.target_speed_m_s,
            clearance_lifts=self.clearance_lifts,
            hand_predicted=self.hand_predicted,
            hand_predicted_since_s=self.controller.hand_memory.carried_since_s,
            goal_stability=self.controller.goal_stability,
            pairing=self.controller.pairing,
            pairings_reachable=self.controller.reachable,
        )

    def stuck(self) -> bool:
        """Held longer than the scenario's ``controller.stuck_after_s`` (sim time)."""
        return is_stuck(self.hold_since_s, self.sim_time_s, self.controller.config.stuck_after_s)

    def stalled(self) -> bool:
        """Servoing longer than ``controller.stall_after_s`` (sim time) without progress."""
        return self.progress.stalled(self.sim_time_s, self.controller.config.stall_after_s)

    def degraded(self) -> str:
        if self.stalled():
            return describe_stall(self.error_px, self.progress, self.sim_time_s, self.lifted)
        if not self.holding:
            return ""
        return describe_hold(
            self.hold_reason, self.hold_since_s, self.sim_time_s, self.controller.config
        )

    def on_pair(self, features: Features, joints: JointState) -> None:
        frozen_before = self.controller.goal_stability is not None
        reach_before = self.controller.reachable
        out = control_step(self.controller, features, joints.position_rad)
        self.error_px, self.converged = out.error_px_rms, out.converged
        self.holding, self.target_remembered = not out.valid, out.target_remembered
        self.hold_reason, self.phase = out.hold_reason, out.phase
        self.hold_since_s, self.sim_time_s = out.hold_since_s, features.header.sim_time_s
        self.clearance_lifts += out.lifted
        self.lifted = out.lifted
        self.hand_predicted = out.hand_predicted
        # On the goal (umay up holds it there) the error has nothing left to fall by.
        # The scenario's scripted events are not the controller's to know (the camera and the
        # encoders are all it has): the run's judge, not this status, waits for their end.
        servoing = out.phase == "servoing" and not out.converged
        self.progress = self.progress.after(self.sim_time_s, out.error_px_rms, servoing)
        self.last_output = twist_message(
            out,
            self.node.header(
                features.header.sim_time_s, features.header.frame_seq, run=features.header.run
            ),
            self.controller.config.mode.value,
        )
        self.pub.put(self.last_output)
        # For status and the log only: after the twist is out, off the loop's latency.
        if not frozen_before:
            self.warn_if_goal_unstable()
        if self.controller.reachable != reach_before:
            self.log_unreachable_pairings()
        velocity = self.controller.target_memory.motion.velocity_m_s(features.header.sim_time_s)
        self.target_speed_m_s = float(np.linalg.norm(velocity))

    def warn_if_goal_unstable(self) -> None:
        """Once, when the constant strategy has frozen a matrix that leaves its goal."""
        stability = self.controller.goal_stability
        if stability is not None and stability <= 0.0:
            log.warning(
                "the constant matrix frozen at this goal makes it unstable %s",
                unstable_goal_consequence(stability),
            )

    def log_unreachable_pairings(self) -> None:
        """When the pairings' goal postures have been checked anew and some are out of reach."""
        reachable = self.controller.reachable
        if reachable is not None and not all(reachable):
            beyond = [k for k, ok in enumerate(reachable) if not ok]
            log.info(
                "corner pairings %s left out: from the present posture the inverse kinematics "
                "does not reach their goal postures within the joint limits%s",
                beyond,
                "" if any(reachable) else " (all of them: the least turn is kept)",
            )

    def on_event(self, key: str, msg: Features | JointState) -> None:
        if not self.runs.admit(msg.header.run, self.new_run):
            self.node.count_dropped(key)  # sent before the sim restarted
            return
        if msg.header.frame_seq == self.pairer.last_paired and self.last_output is not None:
            # A re-published frame (lockstep resend after a restart downstream): answer it
            # again with the same twist instead of stepping the controller twice.
            self.pub.put(self.last_output)
            return
        pair = self.pairer.add(key == self.ctx.keys.features, msg.header.frame_seq, msg)
        if pair is not None:
            self.on_pair(*pair)

    def run(self) -> None:
        self.node.spin(self.ctx.stop, self.on_event)


def main(argv: list[str] | None = None) -> int:
    with ServiceContext("controller", argv) as ctx:  # its session closed however it ends
        ControllerService(ctx).run()
    return 0
