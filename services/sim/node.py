"""Sim service: steps the pybullet world, publishes colour frames, depth images, joint states
and (for evaluation only) ground truth; applies joint velocity commands.

The colour stream runs at ``camera.rgb_hz``; a depth image is taken with the first colour frame
at or after each tick of ``camera.depth_hz``, in whole frames (registered, possibly at a lower
resolution; the schedule is services/sim/schedule.py, the motors' limit services/sim/motors.py). Per
frame the joint state, the ground truth and the previous frame's timing go out first, before
the render, then the depth image if one was taken, then the colour frame, which names the newest
depth image (``depth_frame_seq``). The images are drawn straight into the next slots of the
frame rings (:meth:`TypedPublisher.reserve`) where there are rings, their messages made on those
slots before the render and stamped as they go (:func:`stamped`).

Clock modes:
- lockstep: render frame k, publish it, wait for the command derived from frame k, apply it for
  one camera period, repeat. Deterministic and independent of machine speed. A frame whose
  command does not come back within ``sim.lockstep_resend_s`` is published again (the same
  messages, not a new render).
- realtime: physics follows the wall clock; a frame is rendered at each camera tick, and ticks
  missed while rendering are counted as dropped. The next render waits (bounded) for the last
  frame's command, because a render blocks the whole process (see :meth:`run_realtime`).
"""

from __future__ import annotations

import logging
import time
from typing import TypeVar

import numpy as np

from common import kinematics as kin
from common.config import ClockMode, substeps_per_frame
from common.keys import SERVICES
from common.messages import (
    AppliedCommand,
    DepthFrame,
    ImageData,
    JointState,
    JointVelocityCommand,
    RgbFrame,
    SimTiming,
)
from common.node import Node
from common.publishers import RingPublisher, TypedPublisher
from common.queries import alive_services
from common.runs import new_run
from common.runtime import ServiceContext
from common.session import ENV_SHM
from services.sim.motors import bounded_at_angles, motor_velocities, watchdog_expired
from services.sim.schedule import DepthSchedule, FrameClock
from services.sim.status import SimStatus
from services.sim.truth import truth_message
from services.sim.world import World

log = logging.getLogger("umay.sim")
M = TypeVar("M", RgbFrame, DepthFrame)
# Before the first lockstep frame, once every peer has announced itself: the longest wait for
# the first frame's keys to have subscribers here (SimService.wait_for_subscribers).
SUBSCRIBER_WAIT_S = 0.2


def stamped(message: M) -> M:
    """``message`` with its header's send time now (wall clock): a message made ahead of
    the data it carries is stamped as it goes."""
    message.header.send_time_s = time.time()
    return message


class SimService:
    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        self.scenario = ctx.scenario
        self.world = World(ctx.scenario)
        self.substeps = substeps_per_frame(ctx.scenario.camera.rgb_hz, self.world.physics_dt_s)
        self.frame_seq = 0
        self.run_id = new_run()  # on every message: a restarted sim is a new run (common.runs)
        self.depth_schedule = DepthSchedule.of(ctx.scenario.camera, ctx.scenario.frame_period_s)
        self._last_frame: list[tuple[TypedPublisher, object]] = []  # for a lockstep resend
        self._last_depth: DepthFrame | None = None  # the newest depth image, for a resend
        self.dropped_frames = 0
        self.render_ms = 0.0
        self.started_s = time.monotonic()
        self.node = Node("sim", ctx.keys, ctx.session, self.status_fields)
        keys = ctx.keys
        self.pub_rgb = self.node.publisher(keys.rgb, frames=True)
        self.pub_depth = self.node.publisher(keys.depth, frames=True)
        self.pub_joints = self.node.publisher(keys.joint_state)
        self.pub_truth = self.node.publisher(keys.truth)
        self.pub_timing = self.node.publisher(keys.timing)
        self.applied: list[AppliedCommand] = []  # since the last SimTiming
        self._timing: SimTiming | None = None  # the last frame's, until its command is applied
        self.resends = 0
        self.node.subscribe(keys.joint_command, JointVelocityCommand)
        self.last_command = np.zeros(kin.N_JOINTS)
        self.last_command_s: float | None = None  # wall clock (monotonic)
        self.following = np.zeros(kin.N_JOINTS)  # what the motors follow (realtime: bounded)
        self.watchdog_stops = 0
        self.motor_clamps = 0  # commands beyond the motors' own speed limit

    def status_fields(self) -> SimStatus:
        return SimStatus(
            clock=self.scenario.run.clock.value,
            sim_time_s=round(self.world.sim_time_s, 4),
            frame_seq=self.frame_seq,
            depth_images=self.depth_schedule.depth_images,
            target_hidden=self.world.scene.target_hidden,
            hand_occluded=self.world.scene.hand_occluded_since_s is not None,
            renderer=self.world.renderer,
            renderer_detail=self.world.renderer_detail,
            render_ms=round(self.render_ms, 2),
            dropped_frames=self.dropped_frames,
            watchdog_stops=self.watchdog_stops,
            motor_clamps=self.motor_clamps,
            frames_by_ref=sum(p.meter.by_ref for p in self.frame_publishers),
            frames_by_copy=sum(p.meter.by_copy for p in self.frame_publishers),
            frames_in_place=sum(r.in_place for r in self.rings),
            frames_copied_to_ring=sum(r.copied for r in self.rings),
            frames_copy_reason=self.frames_copy_reason(),
            whole_frames_served=sum(r.served for r in self.rings),
            real_time_factor=round(
                self.world.sim_time_s / max(time.monotonic() - self.started_s, 1e-9), 3
            ),
        )

    @property
    def frame_publishers(self) -> tuple[TypedPublisher, TypedPublisher]:
        return (self.pub_rgb, self.pub_depth)

    @property
    def rings(self) -> list[RingPublisher]:
        """The frame publishers' rings (none when frames by reference are off)."""
        return [p.frames for p in self.frame_publishers if p.frames is not None]

    def frames_copy_reason(self) -> str:
        """Why camera frames go whole instead of by reference ("": they do not)."""
        rings = [p.frames for p in self.frame_publishers]
        if any(r is None for r in rings):
            return f"frames by reference off (${ENV_SHM}=0)"
        return next((r.unavailable for r in rings if r is not None and r.unavailable), "")

    # --- publishing one camera frame ----------------------------------------------------
    def publish_frame(self) -> None:
        """Render and publish camera frame ``frame_seq`` (with a depth image when one is due)."""
        started_publish = time.perf_counter()
        seq, t = self.frame_seq, self.world.sim_time_s
        self.world.update_scene()
        q, qdot = self.world.joint_state()
        with_depth = self.depth_schedule.due(t)
        messages: list[tuple[TypedPublisher, object]] = []  # kept for a lockstep resend

        def put(publisher: TypedPublisher, message: object) -> None:
            publisher.put(message)
            messages.append((publisher, message))

        # Before the render, what the frame does not need: the controller and actuation take
        # the joint state (they pair it with their input by frame_seq) and a run's monitor the
        # truth while the frame is drawn, so no process but vision is woken as the frame goes
        # out (docs/performance.md). The last frame's timing too, with the commands applied
        # since it, the one that answered it among them.
        self._publish_timing()
        put(
            self.pub_joints,
            JointState(
                header=self.node.header(t, seq, run=self.run_id),
                position_rad=q.tolist(),
                velocity_rad_s=qdot.tolist(),
            ),
        )
        truth_header = self.node.header(t, seq, run=self.run_id)
        put(self.pub_truth, truth_message(self.world.truth(), truth_header, q))
        # Drawn straight into the frame rings' next slots where there are rings (no copy on
        # the way to vision); into fresh arrays otherwise.
        k, k_depth = self.world.intrinsics, self.world.depth_intrinsics
        out = (
            self.pub_rgb.reserve((k.height_px, k.width_px, 3), "uint8"),
            self.pub_depth.reserve((k_depth.height_px, k_depth.width_px), "float32")
            if with_depth
            else None,
        )
        schedule = self.depth_schedule.taken(t, seq) if with_depth else self.depth_schedule
        # The messages are made before the render, on the slots it draws into: all they hold
        # but the pixels and the send time is known by then, and made after it they would run
        # on caches the render has emptied, on the frame's way to vision (docs/performance.md).
        # Made after the render where it draws into arrays of its own (no ring, TinyRenderer).
        in_slots = (
            self.world.draws_into_out and out[0] is not None and (out[1] is not None) == with_depth
        )
        prepared = self._frame_messages(t, seq, schedule, *out) if in_slots else None
        render_start_s = time.time()
        started = time.perf_counter()
        rgb, depth_m = self.world.render(with_depth, out)
        self.render_ms = 1000.0 * (time.perf_counter() - started)
        capture_time_s = time.time()
        if prepared is None or rgb is not out[0] or depth_m is not out[1]:
            prepared = self._frame_messages(t, seq, schedule, rgb, depth_m)
        rgb_frame, depth_frame = prepared
        # Each sent as it is stamped; the depth image before the colour frame that names it,
        # so vision has both when the colour frame arrives.
        self.depth_schedule = schedule
        if depth_frame is not None:
            self._last_depth = stamped(depth_frame)
            put(self.pub_depth, depth_frame)
        elif self._last_depth is not None:
            # Not put now, but put again with a resend: a vision started since the depth
            # image was taken has not got the one this frame names.
            messages.append((self.pub_depth, self._last_depth))
        put(self.pub_rgb, stamped(rgb_frame))
        self._last_frame = messages
        # How the frame was made; published when the next one starts (_publish_timing).
        self._timing = SimTiming(
            header=self.node.header(t, seq, run=self.run_id),
            render_start_s=render_start_s,
            capture_time_s=capture_time_s,
            frame_send_time_s=rgb_frame.header.send_time_s,
            with_depth=depth_m is not None,
            dropped_frames=self.dropped_frames,
            resends=self.resends,
        )
        self.node.processing.add(1000.0 * (time.perf_counter() - started_publish))

    def _frame_messages(
        self,
        t: float,
        seq: int,
        schedule: DepthSchedule,
        rgb: np.ndarray,
        depth_m: np.ndarray | None,
    ) -> tuple[RgbFrame, DepthFrame | None]:
        """Frame ``seq``'s colour frame and depth image (None: none taken) on ``rgb`` and
        ``depth_m`` without copying their pixels (ImageData.view_of: the arrays are the ring's
        slots or fresh ones every frame, never changed once sent), to be stamped as they go
        (:func:`stamped`): the publishers commit a slot drawn in place and copy anything else
        into the ring (or into the whole payload, without a ring)."""
        depth_frame = None
        if depth_m is not None:
            depth_frame = DepthFrame(
                header=self.node.header(t, seq, run=self.run_id),
                intrinsics=self.world.depth_intrinsics,
                depth_m=ImageData.view_of(depth_m),
            )
        rgb_frame = RgbFrame(
            header=self.node.header(t, seq, run=self.run_id),
            intrinsics=self.world.intrinsics,
            rgb=ImageData.view_of(rgb),
            depth_frame_seq=schedule.depth_frame_seq,
        )
        return rgb_frame, depth_frame

    def _publish_timing(self) -> None:
        """The last frame's :class:`SimTiming`, with the commands applied since it (none after
        the last frame of a run: its timing is never complete)."""
        if self._timing is not None:
            self.pub_timing.put(self._timing.model_copy(update={"applied": self.applied[-64:]}))
            self._timing, self.applied = None, []

    def republish_frame(self) -> None:
        """The last frame's messages again, unchanged (a lockstep resend)."""
        self.resends += 1
        for publisher, message in self._last_frame:
            publisher.put(message)

    def of_this_run(self, command: JointVelocityCommand) -> bool:
        """A command derived from this run's frames, or a stop (which answers no frame): not
        one left over from a run of the sim before a restart, whose frame numbers meant
        other frames."""
        return command.header.run == self.run_id or command.header.frame_seq < 0

    def answers(self, command: JointVelocityCommand, frame_seq: int) -> bool:
        """Whether ``command`` is this run's for frame ``frame_seq`` (lockstep applies no other)."""
        return command.header.frame_seq == frame_seq and command.header.run == self.run_id

    def apply(self, command: JointVelocityCommand, recv_time_s: float) -> None:
        """``recv_time_s``: when the command arrived (wall clock), for :class:`SimTiming`."""
        self.last_command, clamped = motor_velocities(command.velocity_rad_s)
        self.motor_clamps += clamped
        self.last_command_s = time.monotonic()
        self.set_motors(self.last_command)
        self.applied.append(
            AppliedCommand(
                frame_seq=command.header.frame_seq,
                send_time_s=command.header.send_time_s,
                recv_time_s=recv_time_s,
                applied_time_s=time.time(),
                velocity_rad_s=command.velocity_rad_s,
            )
        )

    def set_motors(self, velocity_rad_s: np.ndarray) -> None:
        self.following = velocity_rad_s
        self.world.set_joint_velocities(velocity_rad_s)

    def hold_joint_limits(self) -> None:
        """Realtime, before each stretch of physics: the motors' velocities bounded again at
        the joints' angles now (:func:`~services.sim.motors.bounded_at_angles`), since the
        command they follow may be far older than this stretch."""
        if not np.any(self.last_command):
            return  # at rest: nothing to bound, no joint state to read
        q_rad, _ = self.world.joint_state()
        following = bounded_at_angles(self.last_command, q_rad)
        if not np.array_equal(following, self.following):
            self.set_motors(following)

    def check_watchdog(self) -> None:
        """Second line of defence behind the actuation deadman: no command, no motion."""
        timeout_s = self.scenario.sim.command_watchdog_s
        if watchdog_expired(self.last_command, self.last_command_s, time.monotonic(), timeout_s):
            self.last_command = np.zeros(kin.N_JOINTS)
            self.set_motors(self.last_command)
            self.watchdog_stops += 1
            log.warning("no joint command for %.2f s: motors stopped", timeout_s)

    # --- clock modes --------------------------------------------------------------------
    def wait_for_peers(self, timeout_s: float = 20.0) -> None:
        """Before the first lockstep frame: wait until the other services announce themselves."""
        deadline = time.monotonic() + timeout_s
        others = set(SERVICES) - {"sim"}
        # Waits as the event loop waiting (Node.wait_idle): the supervisor takes a loop that
        # never started for a start that hangs.
        while not self.ctx.stop.is_set() and time.monotonic() < deadline:
            if others <= alive_services(self.ctx.session, self.ctx.keys, 0.5):
                self.wait_for_subscribers()
                return
            self.node.wait_idle(0.1)
        log.warning("not all services announced themselves; starting anyway")

    def wait_for_subscribers(self) -> None:
        """Until the colour and depth frames and the joint state each have a subscriber here,
        at most :data:`SUBSCRIBER_WAIT_S`. What the start relies on is the order of the peers'
        declarations: each service declares its subscriptions before the token it announces
        itself with, and both reach this session over the same link. This wait is the check
        that they did: a first frame put to nobody would be put again only after
        ``sim.lockstep_resend_s``. It asks for a subscriber per key, not each peer's (two read
        the joint state), and a recorder of every key (``umay run --record``) satisfies it at
        once."""
        until = time.monotonic() + SUBSCRIBER_WAIT_S
        first = (self.pub_rgb, self.pub_depth, self.pub_joints)
        while not self.ctx.stop.is_set() and time.monotonic() < until:
            if all(p.matched for p in first):
                return
            self.node.wait_idle(0.002)

    def run_lockstep(self) -> None:
        self.wait_for_peers()
        resend_s = self.scenario.sim.lockstep_resend_s
        while not self.ctx.stop.is_set():
            self.publish_frame()
            sent = time.monotonic()
            while not self.ctx.stop.is_set():
                event = self.node.next_event(0.05)
                if event is not None and self.answers(event[1], self.frame_seq):
                    self.apply(event[1], self.node.event_recv_time_s)
                    break
                if time.monotonic() - sent > resend_s:
                    log.info("no command for frame %d yet; publishing it again", self.frame_seq)
                    self.republish_frame()
                    sent = time.monotonic()
            else:
                return
            self.world.step(self.substeps)
            self.frame_seq += 1

    def run_realtime(self) -> None:
        """Physics follows the wall clock; a frame is rendered at each camera tick, except that
        after a frame the next render waits (physics running) up to
        ``sim.realtime_command_wait_s`` for that frame's joint command. pybullet keeps the
        interpreter lock while it renders, so a command arriving during a render could not even
        be received before the render ends: without the wait every command would reach the
        motors one render late (docs/performance.md has the figures)."""
        started = time.monotonic()
        clock = FrameClock.of(self.scenario)
        wait_s = self.scenario.sim.realtime_command_wait_s
        awaited: int | None = None  # the frame whose command the next render waits for
        awaited_since = 0.0
        timeout_s = 0.0

        def apply_commands(timeout_s: float) -> None:
            nonlocal awaited
            event = self.node.next_event(timeout_s)  # a command wakes the loop at once
            while event is not None:  # apply every command in order: the newest one stays
                if not self.of_this_run(event[1]):
                    event = self.node.next_event(0.0)
                    continue
                self.apply(event[1], self.node.event_recv_time_s)
                answered = event[1].header.frame_seq
                if awaited is not None and (answered >= awaited or answered < 0):
                    awaited = None  # answered, or a stop that answers no frame: render on
                event = self.node.next_event(0.0)

        while not self.ctx.stop.is_set():
            apply_commands(timeout_s)
            self.check_watchdog()
            wall_s = time.monotonic() - started
            behind = int((wall_s - self.world.sim_time_s) / self.world.physics_dt_s)
            # Catch up a camera period at a time, taking in commands between (one that came
            # during a long render must not wait for all of the catch-up).
            while behind > 0 and not self.ctx.stop.is_set():
                chunk = min(behind, self.substeps)
                self.check_watchdog()  # also between stretches of a catch-up after a long render
                self.hold_joint_limits()
                self.world.step(chunk)
                behind -= chunk
                if behind > 0:
                    apply_commands(0.0)
            waiting = awaited is not None and time.monotonic() - awaited_since < wait_s
            missed = clock.missed(self.world.sim_time_s)
            if missed is not None and not waiting:
                self.dropped_frames += missed
                self.publish_frame()
                awaited, awaited_since = self.frame_seq, time.monotonic()
                self.frame_seq += 1
                clock = clock.after_frame(missed)
            # Until the next physics step is due (rendering may already have overrun it).
            elapsed_s = time.monotonic() - started - wall_s
            timeout_s = max(0.0, self.world.physics_dt_s - elapsed_s)

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
    with ServiceContext("sim", argv) as ctx:  # its session closed however it ends
        SimService(ctx).run()
    return 0
