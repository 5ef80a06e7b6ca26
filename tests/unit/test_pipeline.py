"""One in-process pipeline: the services' pure steps and their composition, in this process
(tests/integration/test_pipeline_vs_distributed.py compares it with the distributed run)."""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest

from common import kinematics as kin
from common.config import ActuationConfig, ScenarioError, load_scenario, substeps_per_frame
from common.messages import EndEffectorTwist, Header
from common.runtime import parse_overrides
from deploy.launch.run_end import EndLimits, HoldState, judge_twist, timeout_detail
from deploy.launch.run_inprocess import run_scenario_inprocess
from services.actuation.limiter import LimiterState, actuation_step
from services.pipeline import STAGES, Pipeline
from services.sim.motors import bounded_at_angles, motor_velocities, watchdog_expired
from services.sim.schedule import DepthSchedule
from services.vision.tracking import TrackerState


# --- the sim's schedule and motors --------------------------------------------------------
def depth_frames(rgb_hz: float, depth_hz: float, frames: int, physics_hz: int = 240) -> list[int]:
    scenario = short(
        None,
        f"camera.rgb_hz={rgb_hz}",
        f"camera.depth_hz={depth_hz}",
        f"sim.physics_hz={physics_hz}",
    )
    schedule = DepthSchedule.of(scenario.camera, scenario.frame_period_s)
    taken = []
    t = 0.0
    for seq in range(frames):
        if schedule.due(t):
            schedule = schedule.taken(t, seq)
            taken.append(seq)
            assert schedule.depth_frame_seq == seq
        t += scenario.frame_period_s  # accumulated in whole physics steps, as the world's clock
    assert schedule.depth_images == len(taken)
    return taken


def test_depth_comes_with_every_frame_at_equal_rates_and_every_third_at_a_third() -> None:
    assert depth_frames(30.0, 30.0, 12) == list(range(12))
    assert depth_frames(30.0, 10.0, 30) == list(range(0, 30, 3))
    assert depth_frames(15.0, 1.0, 46) == [0, 15, 30, 45]


@pytest.mark.parametrize("physics_hz", [100, 70])
def test_the_depth_ticks_follow_the_frames_whole_physics_steps(physics_hz: int) -> None:
    """At 100 Hz physics a 30 Hz frame is 3 steps, 0.030 s: ticks every 1/30 s fell behind
    the frames and every tenth frame went without its depth image."""
    assert depth_frames(30.0, 30.0, 60, physics_hz) == list(range(60))
    assert depth_frames(30.0, 10.0, 60, physics_hz) == list(range(0, 60, 3))


def test_a_late_frame_does_not_shift_the_depth_grid() -> None:
    schedule = DepthSchedule(period_s=0.1).taken(0.0, 0)
    assert not schedule.due(0.05)
    late = schedule.taken(0.25, 7)  # the frame came 0.15 s after the tick at 0.1
    assert late.next_depth_s == pytest.approx(0.3)  # the grid's next tick, not 0.35
    assert late.depth_frame_seq == 7 and late.depth_images == 2


def test_substeps_cover_one_camera_period() -> None:
    assert substeps_per_frame(30.0, 1.0 / 240.0) == 8
    assert substeps_per_frame(15.0, 1.0 / 240.0) == 16
    assert substeps_per_frame(1000.0, 1.0 / 240.0) == 1


def test_the_motors_clip_to_their_own_limit_and_say_so() -> None:
    limit = np.asarray(kin.JOINT_VELOCITY_LIMIT_RAD_S) * np.ones(kin.N_JOINTS)
    within = limit * np.array([0.5, -0.5, 0.0, 0.1, -0.1, 1.0])
    follows, clamped = motor_velocities(within.tolist())
    assert not clamped and np.array_equal(follows, within)
    follows, clamped = motor_velocities((limit * np.array([2.0, -3.0, 0, 0, 0, 0])).tolist())
    assert clamped and follows[0] == limit[0] and follows[1] == -limit[1]
    assert np.array_equal(follows[2:], np.zeros(4))


def test_the_motors_hold_the_joint_limits_whatever_the_command_s_age() -> None:
    """A command toward a limit stays in force for as long as nothing replaces it (realtime:
    until the next frame's, a deadman or a watchdog stop). Bounded again at the joint's angle
    before each stretch of physics, the joint slows down on its own and never crosses the
    limit; followed as it was given, it did, by degrees."""
    upper = kin.JOINT_UPPER_RAD[0]
    command = np.zeros(kin.N_JOINTS)
    command[0] = kin.JOINT_VELOCITY_LIMIT_RAD_S[0]  # at full speed towards it, from 20° before
    # The longest stretch the sim follows one bound for: a frame of the slowest camera allowed.
    dt_s = substeps_per_frame(9.0, 1.0 / 240.0) / 240.0

    def joint_after(seconds: float, bounded: bool) -> float:
        q = np.zeros(kin.N_JOINTS)
        q[0] = upper - np.deg2rad(20.0)
        for _ in range(round(seconds / dt_s)):
            q += (bounded_at_angles(command, q) if bounded else command) * dt_s
        return float(q[0])

    assert joint_after(0.3, bounded=False) > upper  # a watchdog's 0.3 s at speed: past it
    assert upper - np.deg2rad(1.0) < joint_after(3.0, bounded=True) <= upper  # never past
    with pytest.raises(ScenarioError, match=r"camera\.rgb_hz: Input should be greater than or"):
        short(None, "camera.rgb_hz=8.0", "camera.depth_hz=8.0")  # a frame would carry it past
    # 9 Hz in whole steps of 50 Hz physics is a 0.12 s frame: longer than the zone's crossing.
    with pytest.raises(ScenarioError, match=r"a joint could pass its limit within a frame"):
        short(None, "camera.rgb_hz=9.0", "camera.depth_hz=9.0", "sim.physics_hz=50")
    assert short(None, "camera.rgb_hz=9.0", "camera.depth_hz=9.0").frame_period_s < 0.1164
    at = np.zeros(kin.N_JOINTS)
    at[0] = upper - np.deg2rad(1.0)  # a tenth of the zone left: a tenth of the speed
    assert bounded_at_angles(command, at)[0] == pytest.approx(0.1 * command[0])
    assert bounded_at_angles(-command, at)[0] == -command[0]  # away from it: untouched
    assert np.array_equal(bounded_at_angles(command, np.zeros(kin.N_JOINTS)), command)


def test_the_watchdog_stops_motors_left_moving_on_an_old_command() -> None:
    """The sim's second line of defence: motors that still follow a command older than the
    watchdog's time stop; a fresh command, motors at rest, or no command yet never trip it."""
    moving = np.zeros(kin.N_JOINTS)
    moving[2] = 0.3
    timeout_s = 0.3
    assert watchdog_expired(moving, 10.0, 10.31, timeout_s)  # 0.31 s with no command
    assert not watchdog_expired(moving, 10.0, 10.29, timeout_s)  # within its time
    assert not watchdog_expired(np.zeros(kin.N_JOINTS), 10.0, 99.0, timeout_s)  # at rest
    assert not watchdog_expired(moving, None, 99.0, timeout_s)  # never commanded


# --- actuation's limiter --------------------------------------------------------------------
Q = np.array([-1.559, 0.952, -1.832, 1.487, 0.600, -0.070])  # the default start
TWIST = np.array([0.05, -0.02, 0.03, 0.0, 0.1, 0.0])


def test_the_first_command_from_rest_has_no_time_base_and_stays_at_rest() -> None:
    cfg = ActuationConfig(max_joint_acceleration_rad_s2=2.0)
    step = actuation_step(cfg, LimiterState(), TWIST, True, Q, 0.5)
    assert step.reason == "track" and step.joint is not None and step.joint.clamps.acceleration
    assert np.array_equal(step.velocity_rad_s, np.zeros(kin.N_JOINTS))
    assert step.state.previous_sim_s == 0.5


def test_the_change_between_commands_is_bounded_by_the_acceleration_over_sim_time() -> None:
    cfg = ActuationConfig(max_joint_acceleration_rad_s2=2.0)
    state = LimiterState().commanded(np.zeros(kin.N_JOINTS), 1.0)
    step = actuation_step(cfg, state, TWIST, True, Q, 1.0 + 1.0 / 30.0)
    change = np.max(np.abs(step.velocity_rad_s))
    assert change == pytest.approx(2.0 / 30.0)  # the largest joint change: a · dt
    unlimited = actuation_step(ActuationConfig(max_joint_acceleration_rad_s2=1000.0), state, TWIST,
                               True, Q, 1.0 + 1.0 / 30.0)  # fmt: skip
    assert np.max(np.abs(unlimited.velocity_rad_s)) > change
    # The same direction in joint space, scaled down.
    ratio = step.velocity_rad_s / unlimited.velocity_rad_s
    assert np.allclose(ratio, ratio[0])


def test_a_gap_between_commands_allows_no_larger_jump_than_one_camera_period() -> None:
    """The change reaches the motors at once however long they held the command before (frames
    skipped in realtime, a stall): the acceleration limit counts one camera period at most,
    and the rounding of consecutive lockstep frames' sim times is not a gap."""
    cfg = ActuationConfig(max_joint_acceleration_rad_s2=2.0)
    period = 1.0 / 30.0
    state = LimiterState().commanded(np.zeros(kin.N_JOINTS), 1.0)
    after_a_second = actuation_step(cfg, state, TWIST, True, Q, 2.0, max_dt_s=period)
    assert np.max(np.abs(after_a_second.velocity_rad_s)) == pytest.approx(2.0 * period)
    uncapped = actuation_step(cfg, state, TWIST, True, Q, 2.0)
    assert np.max(np.abs(uncapped.velocity_rad_s)) > 3 * 2.0 * period  # a second's worth
    at_25_hz = short(None, "camera.rgb_hz=25.0", "camera.depth_hz=25.0").frame_period_s
    assert at_25_hz == pytest.approx(10 / 240)  # whole physics steps: not 1/25 s
    rounded = 1.0 + period * (1.0 + 1e-15)  # one period, as accumulated physics steps give it
    capped = actuation_step(cfg, state, TWIST, True, Q, rounded, max_dt_s=period)
    as_before = actuation_step(cfg, state, TWIST, True, Q, rounded)
    assert np.array_equal(capped.velocity_rad_s, as_before.velocity_rad_s)


def test_a_hold_stops_at_once_and_the_next_motion_ramps_from_rest() -> None:
    cfg = ActuationConfig(max_joint_acceleration_rad_s2=2.0)
    moving = LimiterState().commanded(np.full(kin.N_JOINTS, 0.3), 2.0)
    hold = actuation_step(cfg, moving, TWIST, False, Q, 2.1)
    assert hold.reason == "hold" and hold.joint is None
    assert np.array_equal(hold.velocity_rad_s, np.zeros(kin.N_JOINTS))
    assert hold.state.previous_sim_s == 2.1 and not np.any(hold.state.previous_rad_s)
    again = actuation_step(cfg, hold.state, TWIST, True, Q, 2.2)
    assert np.max(np.abs(again.velocity_rad_s)) == pytest.approx(2.0 * 0.1)
    assert LimiterState.at_rest().previous_sim_s is None


# --- the end of a run -------------------------------------------------------------------------
def twist(seq: int, t_s: float, valid: bool = True, converged: bool = False) -> EndEffectorTwist:
    return EndEffectorTwist(
        header=Header(seq=seq, sim_time_s=t_s, send_time_s=0.0, frame_seq=seq),
        linear_m_s=[0.0, 0.0, 0.0],
        angular_rad_s=[0.0, 0.0, 0.0],
        valid=valid,
        hold_reason="" if valid else "hand lost",
        mode="dynamic",
        error_px_rms=2.5 if valid else 0.0,
        converged=converged,
    )


def test_convergence_counts_only_after_the_events_and_the_timeout_names_the_last_twist() -> None:
    limits = EndLimits(timeout_s=3.0, not_before_s=2.0, stuck_after_s=10.0)
    hold, end = judge_twist(limits, HoldState(), twist(10, 1.0, converged=True))
    assert end is None
    hold, end = judge_twist(limits, hold, twist(70, 2.0, converged=True))
    assert end is not None and (end.reason, end.frame, end.detail) == ("converged", 70, "")
    last = twist(90, 3.0)
    _, end = judge_twist(limits, hold, last)
    assert end is not None and end.reason == "timeout" and end.frame == 90
    assert end.detail == timeout_detail(last, 3.0) and "2.500 px" in end.detail
    acquiring = last.model_copy(update={"hold_reason": "acquiring: target partial, attempt 3/4"})
    assert timeout_detail(acquiring, 3.0) == (
        "3 s simulated; still acquiring: target partial, attempt 3/4"
    )  # no image error: an acquiring twist has none


# --- the pipeline ---------------------------------------------------------------------------
def short(scenario_path: str | None = None, *overrides: str):
    return load_scenario(scenario_path, parse_overrides(list(overrides)))


def test_vision_measured_again_on_the_same_inputs_gives_the_same_features() -> None:
    """The bench's warm second call: the step is pure, the pipeline's state unchanged by it."""
    again = []
    with Pipeline(short(None, "camera.width_px=320", "camera.height_px=240")) as pipeline:
        for _ in range(3):
            frame = pipeline.step(after_vision=lambda measure: again.append(measure()))
            features = again[-1].features(frame.features.header, frame.features.intrinsics)
            assert features == frame.features
            assert set(frame.stage_s) == set(STAGES) and min(frame.stage_s.values()) >= 0.0
            assert frame.truth is not None and frame.truth.header.frame_seq == frame.frame_seq
        assert pipeline.frame_seq == 3 and frame.depth_frame_seq == 2


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def test_many_runs_in_one_process_leave_no_descriptors_or_threads_behind() -> None:
    import threading

    scenario = short(None, "camera.width_px=160", "camera.height_px=120", "run.timeout_s=0.1")
    counts = []
    for _ in range(8):
        result = run_scenario_inprocess(scenario)
        assert result.reason == "timeout" and result.frames == 4
        counts.append((open_fds(), threading.active_count()))
    assert counts[-1] == counts[1], counts  # the first run may open lasting caches


@pytest.mark.parametrize(
    "restart_at, why",
    [
        (20, "the hand turned past 45° since the start: labelled a quarter turn away"),
        (110, "the hand over the target: a new vision has no view of it to look behind"),
    ],
)
def test_a_vision_restarted_mid_run_leaves_the_hand_converging(restart_at: int, why: str) -> None:
    """What a supervisor's restart of vision leaves the loop with: a tracker with no labels,
    no views, no motions (TrackerState()), the controller's state kept. The hand still
    reaches the target (it was servoed to the wrong pairing, or held over a target the new
    vision called lost, before the controller followed relabelled corners and took a target
    vision cannot tell about as maybe hidden)."""
    frames = []
    with Pipeline(short()) as pipeline:
        for seq in range(400):
            if seq == restart_at:
                pipeline.tracker = TrackerState()
            frame = pipeline.step()
            frames.append(frame)
            if seq > restart_at and frame.control.converged:
                break
    assert frames[-1].control.converged, (why, frames[-1].control.status)
    assert frames[restart_at].features.hand.state == "visible"  # no loss between the labels


def test_a_deadman_no_shorter_than_the_watchdog_is_refused_by_name() -> None:
    """The deadman is the first stop and the sim's watchdog the second: a scenario that has
    them the other way round is bad input, named, before anything starts."""
    with pytest.raises(ScenarioError, match=r"actuation\.deadman_timeout_s \(0\.3\) not below"):
        short(None, "actuation.deadman_timeout_s=0.3")
    assert short(None, "actuation.deadman_timeout_s=0.29").actuation.deadman_timeout_s == 0.29


@pytest.mark.parametrize(
    ("field", "too_large", "largest"),
    [("max_linear_m_s", 5.01, 5.0), ("max_angular_rad_s", 20.5, 20.0)],
)
def test_a_twist_clamp_the_wire_cannot_carry_is_refused_by_name(field, too_large, largest):
    """The controller's clamp bounds what it publishes: above the wire's range, its own twist
    message would fail validation and end it."""
    with pytest.raises(ScenarioError, match=rf"controller\.{field}: Input should be less than"):
        short(None, f"controller.{field}={too_large}")
    assert getattr(short(None, f"controller.{field}={largest}").controller, field) == largest


def test_the_twist_carries_the_laws_goal_paired_with_the_hands_corners() -> None:
    """Each twist of the law carries s* in the hand's corner order: its error to the hand's
    corners is the twist's own error_px_rms, also while the hand hides the target (servoed on
    memory). A goal the wire cannot carry is left out, not a reason to fail the twist."""
    from services.controller.step import twist_message

    scenario = load_scenario(None, parse_overrides(["camera.width_px=320", "camera.height_px=240"]))
    hidden = 0
    with Pipeline(scenario, truth=False) as pipeline:
        for _ in range(60):
            r = pipeline.step()
            if not r.twist.servoing:
                assert r.twist.goal_px is None
                continue
            hand = np.array(r.features.hand.corners_px)
            if r.features.hand.usable:
                e = hand - np.array(r.twist.goal_px)
                assert float(np.sqrt(np.mean(e**2))) == pytest.approx(r.twist.error_px_rms)
            hidden += not r.features.target.usable
        far = r.control.goal_px * 1e6  # a remembered goal carried far out of the image
        out = twist_message(replace(r.control, goal_px=far), r.twist.header, "dynamic")
    assert hidden > 0 and out.goal_px is None
