"""The safety behaviours of the service shells, beyond their pure rules: actuation's deadman as
the service runs it (stops sent, counted, reported, never taken for a frame's answer), its
hold and position-limit counters, the sim's motors holding their speed and angle limits and its
watchdog stopping them, and the controller and actuation answering a lockstep resend without
stepping again. Driven as in test_sim_runs.py: the handlers called directly in one process, on
a loopback Zenoh session under a unique key prefix (the ``ctx`` fixture), on the default
scenario's first frames."""

from __future__ import annotations

import numpy as np
import pytest

from common import kinematics as kin
from common.config import load_scenario
from common.messages import EndEffectorTwist, Header, JointState
from common.runtime import parse_overrides
from services.sim.motors import bounded_at_angles
from tests.services_in_process import (
    LONG_TIMEOUTS,
    RUN_A,
    command,
    feed,
    in_run,
    published,
    realtime_sim,
)

LIMIT = kin.JOINT_VELOCITY_LIMIT_RAD_S


# --- actuation's deadman --------------------------------------------------------------------
def test_actuation_s_deadman_sends_one_counted_stop_that_never_answers_a_resend(
    ctx,
    pipeline_frames,
) -> None:
    """No stop before the first twist (the motors are at rest: nothing to stop). Once the last
    valid twist is older than ``actuation.deadman_timeout_s``, ``check_deadman`` sends one zero
    command (reason ``deadman``, frame_seq -1: it answers no frame), again only after another
    timeout, counts each in ``deadman_stops`` and reports the service degraded. The stop must
    not become the answer to a lockstep resend (the sim would take a zero for the frame's
    command), nor reset the limiter (in lockstep it never reaches the motors)."""
    from services.actuation.node import ActuationService

    ctx.scenario = load_scenario(None, parse_overrides(LONG_TIMEOUTS))
    service = ActuationService(ctx)  # type: ignore[arg-type]
    try:
        service.node.ready()  # running: its status reports a degradation
        sent = published(service)
        service.check_deadman()  # before any twist
        assert sent == [] and service.deadman_stops == 0
        assert service.node.status().state == "running"
        assert service.status_fields().deadman is False  # at rest, not stopped
        feed(service, ctx, pipeline_frames[:3])
        tracked = list(sent)
        assert [c.header.frame_seq for c in tracked] == [0, 1, 2]
        assert {c.reason for c in tracked} == {"track"} and np.any(tracked[-1].velocity_rad_s)
        service.check_deadman()  # the twist is fresh: nothing to stop
        assert len(sent) == 3 and service.deadman_stops == 0
        assert service.status_fields().deadman is False
        assert service.node.status().degraded_reason == ""

        limiter = service.limiter
        timeout = ctx.scenario.actuation.deadman_timeout_s
        service.last_valid_twist_s -= timeout + 0.05  # no twist since, for longer than that
        service.check_deadman()
        assert len(sent) == 4
        stop = sent[-1]
        assert stop.reason == "deadman" and stop.velocity_rad_s == [0.0] * kin.N_JOINTS
        assert stop.header.frame_seq == -1 and stop.header.run == RUN_A
        assert stop.header.sim_time_s == pipeline_frames[2].twist.header.sim_time_s
        assert service.deadman_stops == 1
        fields = service.status_fields()
        assert fields.deadman is True and fields.deadman_stops == 1
        status = service.node.status()
        assert status.state == "degraded" and status.degraded_reason.startswith("deadman")
        assert service.limiter is limiter  # not reset by a stop the motors may never get

        service.check_deadman()  # at once again: one stop per timeout, not one per idle tick
        assert len(sent) == 4 and service.deadman_stops == 1
        service.last_deadman_s -= timeout + 0.05  # the timeout again, still no twist
        service.check_deadman()
        assert len(sent) == 5 and sent[-1].reason == "deadman" and service.deadman_stops == 2

        # The sim resends frame 2: the answer is frame 2's command again, not the stop.
        service.on_event(ctx.keys.twist, in_run(pipeline_frames[2].twist, RUN_A))
        assert sent[-1] is tracked[-1] and sent[-1].reason == "track"
        assert service.deadman_stops == 2

        # A fresh valid twist ends it.
        feed(service, ctx, pipeline_frames[3:4])
        assert sent[-1].header.frame_seq == 3 and sent[-1].reason == "track"
        assert service.status_fields().deadman is False
        assert service.node.status().state == "running"
    finally:
        service.node.close()


# --- actuation's counters -------------------------------------------------------------------
def test_actuation_counts_a_hold_stop_for_an_invalid_twist(ctx, pipeline_frames) -> None:
    """A twist the controller marks invalid (a hold) is answered at once with zero velocity,
    whatever numbers the twist carries, reason ``hold``, and counted in ``hold_stops``; valid
    twists are not."""
    from services.actuation.node import ActuationService

    service = ActuationService(ctx)  # type: ignore[arg-type]
    try:
        sent = published(service)
        feed(service, ctx, pipeline_frames[:2])
        assert service.counts["hold_stops"] == 0
        f = pipeline_frames[2]
        assert np.any(f.twist.linear_m_s)  # numbers a hold must not pass on
        hold = f.twist.model_copy(update={"valid": False, "hold_reason": "features missing"})
        service.on_event(ctx.keys.joint_state, in_run(f.joints, RUN_A))
        service.on_event(ctx.keys.twist, in_run(hold, RUN_A))
        assert sent[-1].header.frame_seq == 2 and sent[-1].reason == "hold"
        assert sent[-1].velocity_rad_s == [0.0] * kin.N_JOINTS
        assert service.counts["hold_stops"] == 1
        assert service.status_fields().hold_stops == 1
        feed(service, ctx, pipeline_frames[3:4])  # tracking again
        assert sent[-1].reason == "track" and service.status_fields().hold_stops == 1
    finally:
        service.node.close()


def motion_frame(
    seq: int, q: np.ndarray, wanted: np.ndarray, period_s: float, like: EndEffectorTwist
) -> tuple[JointState, EndEffectorTwist]:
    """Frame ``seq`` (run 1, at ``seq`` camera periods) with the arm standing at ``q`` and a
    valid twist (otherwise ``like``) that is the joint motion ``wanted`` there."""
    header = Header(seq=seq, sim_time_s=seq * period_s, send_time_s=1.0, frame_seq=seq, run=1)
    twist = kin.geometric_jacobian(q) @ wanted
    joints = JointState(header=header, position_rad=q.tolist(), velocity_rad_s=[0.0] * 6)
    return joints, like.model_copy(
        update={
            "header": header,
            "linear_m_s": twist[:3].tolist(),
            "angular_rad_s": twist[3:].tolist(),
            "valid": True,
        }
    )


def test_actuation_counts_a_command_slowed_at_joint_limits_once(ctx, pipeline_frames) -> None:
    """A twist that asks joints 1 and 2 to move on past the limits they stand at gets a
    command with no speed towards either limit, the joints reported saturated, and the
    command counted once in ``position_limit_clamps`` (commands, not joints); the same
    motion away from the limits counts nothing."""
    from services.actuation.node import ActuationService

    wanted = np.array([0.5, -0.5, 0.0, 0.0, 0.0, 0.0])  # joint 1 up, joint 2 down
    q_free = np.array(pipeline_frames[0].joints.position_rad)
    q_at_limits = q_free.copy()
    q_at_limits[0], q_at_limits[1] = kin.JOINT_UPPER_RAD[0], kin.JOINT_LOWER_RAD[1]
    like, period = pipeline_frames[0].twist, ctx.scenario.frame_period_s
    service = ActuationService(ctx)  # type: ignore[arg-type]
    try:
        sent = published(service)
        for seq, q in enumerate([q_free, q_free, q_at_limits]):
            joints, twist = motion_frame(seq, q, wanted, period, like)
            service.on_event(ctx.keys.joint_state, joints)
            service.on_event(ctx.keys.twist, twist)
            if seq == 1:  # away from the limits: moving as asked, nothing counted
                assert sent[-1].velocity_rad_s[0] > 0 > sent[-1].velocity_rad_s[1]
                assert service.counts["position_limit_clamps"] == 0
        at_limits = sent[-1]
        assert at_limits.header.frame_seq == 2 and at_limits.reason == "track"
        assert at_limits.velocity_rad_s[0] <= 0.0 <= at_limits.velocity_rad_s[1]
        fields = service.status_fields()
        assert fields.position_limit_clamps == 1
        assert {0, 1} <= set(fields.saturated_joints)
    finally:
        service.node.close()


def test_actuation_counts_a_joint_held_at_its_bound_near_a_limit(ctx, pipeline_frames) -> None:
    """Five degrees short of its upper limit, joint 1 asked for 1 rad/s towards it gets no
    more than its bound there (half its speed limit) and the other joints take on its share
    of the twist. Every such command counts in ``position_limit_clamps``, also once the
    command has settled at the bound, where no later clip acts and only the joints held by
    the redistribution tell that a limit slowed the command."""
    from services.actuation.node import ActuationService

    q = np.array(pipeline_frames[0].joints.position_rad)
    q[0] = kin.JOINT_UPPER_RAD[0] - np.deg2rad(5.0)
    wanted = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    like, period = pipeline_frames[0].twist, ctx.scenario.frame_period_s
    service = ActuationService(ctx)  # type: ignore[arg-type]
    try:
        sent = published(service)
        for seq in range(6):  # the ramp up, then the settled command
            joints, twist = motion_frame(seq, q, wanted, period, like)
            service.on_event(ctx.keys.joint_state, joints)
            service.on_event(ctx.keys.twist, twist)
        settled = np.array(sent[-1].velocity_rad_s)
        assert np.array_equal(settled, sent[-2].velocity_rad_s)  # past the ramp
        assert settled[0] == pytest.approx(0.5 * LIMIT[0])  # held at its bound
        assert np.any(settled[1:])  # the others moving in its place
        fields = service.status_fields()
        assert fields.position_limit_clamps == 6 and fields.saturated_joints == [0]
    finally:
        service.node.close()


# --- the sim's motors -----------------------------------------------------------------------
def test_the_sim_s_motors_hold_their_speed_limit_and_slow_down_near_a_joint_limit(ctx) -> None:
    """Whatever a command says, the motors follow no joint faster than its speed limit
    (``JOINT_VELOCITY_LIMIT_RAD_S``), and each command beyond it is counted once in
    ``motor_clamps``. Realtime, a command stays in force until the next one: bounded again at
    the angles the joints have now (``hold_joint_limits``), a joint driven towards a limit
    slows down as it nears it and stops short of it, while the command is kept and the other
    joints, and motion away from the limit, are left alone."""
    with realtime_sim(ctx) as sim:
        command(sim, [0.0, 0.0, 2.0, 0.0, 0.0, -3.0])  # two joints beyond the limit: one command
        assert np.array_equal(sim.following, [0.0, 0.0, LIMIT[2], 0.0, 0.0, -LIMIT[5]])
        assert sim.motor_clamps == 1 and sim.status_fields().motor_clamps == 1
        command(sim, [0.0, 0.0, 1.0, 0.0, 0.0, -1.0])  # within it: followed as it is, not counted
        assert np.array_equal(sim.following, [0.0, 0.0, 1.0, 0.0, 0.0, -1.0])
        assert sim.motor_clamps == 1

        q, _ = sim.world.joint_state()
        upper = kin.JOINT_UPPER_RAD[2]
        q[2] = upper - np.deg2rad(2.0)  # a fifth of the slow-down zone left
        sim.world.reset(q)
        towards = np.array([0.0, 0.3, 1.0, 0.0, 0.0, 0.0])  # joint 3 towards its upper limit
        command(sim, towards.tolist())
        assert np.array_equal(sim.following, towards)  # applied as it came
        sim.hold_joint_limits()
        expected = bounded_at_angles(towards, sim.world.joint_state()[0])
        assert np.array_equal(sim.following, expected)
        assert sim.following[2] == pytest.approx(LIMIT[2] * 0.2, rel=1e-3)  # slowed
        assert sim.following[1] == 0.3  # far from its limits: as commanded
        assert np.array_equal(sim.last_command, towards)  # the command itself is kept
        for _ in range(30):  # a second of physics on that one command, as run_realtime does
            sim.hold_joint_limits()
            sim.world.step(sim.substeps)
        q_now, _ = sim.world.joint_state()
        assert upper - np.deg2rad(2.0) < q_now[2] <= upper + np.deg2rad(0.1)
        assert 0 <= sim.following[2] < 0.1 * LIMIT[2]  # slower still, near the limit
        assert sim.motor_clamps == 1  # bounding at angles is not a speed clamp

        command(sim, [0.0, 0.0, -1.0, 0.0, 0.0, 0.0])  # away from the limit: not slowed
        sim.hold_joint_limits()
        assert np.array_equal(sim.following, [0.0, 0.0, -1.0, 0.0, 0.0, 0.0])


def test_the_sim_s_watchdog_stops_motors_its_commands_stopped_reaching(ctx) -> None:
    """Realtime: a command stays in force until the next one; when none comes for longer than
    ``sim.command_watchdog_s`` (actuation dead or frozen before it could send the stop), the
    sim stops the motors itself, counts it in its status, and the arm comes to rest."""
    with realtime_sim(ctx, *LONG_TIMEOUTS) as sim:
        moving = [0.0, 0.0, 0.3, 0.0, 0.0, 0.0]
        command(sim, moving)
        sim.world.step(24)
        assert sim.world.joint_state()[1][2] == pytest.approx(0.3, abs=0.02)
        sim.check_watchdog()  # the command is fresh: left alone
        assert sim.watchdog_stops == 0 and np.array_equal(sim.following, moving)
        assert sim.last_command_s is not None
        sim.last_command_s -= ctx.scenario.sim.command_watchdog_s + 0.01  # then silence
        sim.check_watchdog()
        assert sim.watchdog_stops == 1 and not np.any(sim.following)
        assert sim.status_fields().watchdog_stops == 1
        sim.world.step(24)
        assert np.abs(sim.world.joint_state()[1]).max() < 1e-3  # at rest
        sim.check_watchdog()  # at rest: nothing more to stop
        assert sim.watchdog_stops == 1


# --- lockstep resends -----------------------------------------------------------------------
def test_the_controller_answers_a_resent_frame_with_the_same_twist_without_stepping(
    ctx,
    pipeline_frames,
) -> None:
    """A lockstep resend (the sim publishes frame k again when its command did not come back)
    brings frame k's joint state and features again: each gets the very twist frame k got,
    and the controller is not stepped on the frame a second time (its memories and progress
    would advance, and two lockstep runs would differ)."""
    from services.controller.node import ControllerService

    service = ControllerService(ctx)  # type: ignore[arg-type]
    try:
        steps: list[int] = []
        on_pair = service.on_pair
        service.on_pair = lambda features, joints: (  # type: ignore[method-assign]
            steps.append(features.header.frame_seq),
            on_pair(features, joints),
        )
        twists = published(service)
        feed(service, ctx, pipeline_frames[:3], other="features")
        assert [t.header.frame_seq for t in twists] == [0, 1, 2] and steps == [0, 1, 2]
        answer, progress = twists[-1], service.progress
        resent = pipeline_frames[2]
        service.on_event(ctx.keys.joint_state, in_run(resent.joints, RUN_A))
        service.on_event(ctx.keys.features, in_run(resent.features, RUN_A))
        assert steps == [0, 1, 2] and service.progress is progress  # not stepped again
        assert len(twists) == 5 and twists[3] is answer and twists[4] is answer
        assert service.last_output is answer
        feed(service, ctx, pipeline_frames[3:4], other="features")  # and on it goes
        assert twists[-1].header.frame_seq == 3 and steps == [0, 1, 2, 3]
        assert twists[-1].header.seq == answer.header.seq + 1  # no twist made in between
    finally:
        service.node.close()


def test_actuation_answers_a_resent_frame_with_the_same_command_without_stepping(
    ctx,
    pipeline_frames,
) -> None:
    """Frame k's twist and joint state delivered again (a lockstep resend) get the very
    command frame k got; the limiter is not stepped again (a second step on the same frame
    would bound the change against the frame's own command, with no time between) and no
    clamp is counted twice."""
    from services.actuation.node import ActuationService

    service = ActuationService(ctx)  # type: ignore[arg-type]
    try:
        sent = published(service)
        feed(service, ctx, pipeline_frames[:4])
        assert [c.header.frame_seq for c in sent] == [0, 1, 2, 3]
        answer, limiter, counts = sent[-1], service.limiter, dict(service.counts)
        assert np.any(answer.velocity_rad_s)
        resent = pipeline_frames[3]
        service.on_event(ctx.keys.twist, in_run(resent.twist, RUN_A))
        service.on_event(ctx.keys.joint_state, in_run(resent.joints, RUN_A))
        assert service.limiter is limiter and service.counts == counts  # not stepped again
        assert len(sent) == 6 and sent[4] is answer and sent[5] is answer
        feed(service, ctx, pipeline_frames[4:5])
        assert sent[-1].header.frame_seq == 4 and sent[-1].header.seq == answer.header.seq + 1
    finally:
        service.node.close()
