"""A restarted sim begins a new run (common/runs.py): vision, the controller and actuation start
it afresh and drop what is left over from the run before; vision answers a lockstep resend
without measuring the frame again; actuation resumed after a freeze ramps from rest. The
services' event handlers are driven directly (one process, a loopback Zenoh session under a
unique key prefix), on the messages the in-process pipeline computes for the default scenario's
first frames."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from common.config import load_scenario
from common.messages import (
    Header,
    JointVelocityCommand,
)
from common.runs import REVIVE_AFTER, RunVerdict, RunWatch, new_run
from tests.services_in_process import RUN_A, RUN_B, feed, in_run, published


def test_runs_are_told_apart_and_a_replaced_one_stays_over() -> None:
    watch = RunWatch()
    assert watch.see(RUN_A) is RunVerdict.NEW  # the first one seen
    assert watch.see(RUN_A) is RunVerdict.SAME
    assert watch.see(RUN_B) is RunVerdict.NEW  # the sim restarted
    assert watch.see(RUN_A) is RunVerdict.OVER  # in flight from before: left over
    assert watch.current == RUN_B
    runs = {new_run() for _ in range(100)}
    assert len(runs) == 100 and 0 not in runs  # 0 is left to unstamped messages
    started: list[int] = []
    watch = RunWatch()
    used = [watch.admit(run, lambda: started.append(watch.current)) for run in (1, 1, 2, 1, 2)]
    assert used == [True, True, True, False, True] and started == [1, 2]


def test_a_stray_message_of_a_run_never_seen_does_not_stop_the_live_run_for_good() -> None:
    """Run 22 in progress; one message of run 11, never seen (sent long before, a process
    frozen meanwhile), takes its place, and 22's messages then read as left over. Heard
    REVIVE_AFTER times in a row, 22 is the live run after all and takes the place back; a
    backlog of an ended run interleaved with the new run's messages revives nothing."""
    watch = RunWatch()
    assert [watch.see(r) for r in (22, 11)] == [RunVerdict.NEW, RunVerdict.NEW]
    over = [watch.see(22) for _ in range(REVIVE_AFTER - 1)]
    assert over == [RunVerdict.OVER] * (REVIVE_AFTER - 1) and watch.current == 11
    assert watch.see(22) is RunVerdict.NEW and watch.current == 22
    assert watch.see(22) is RunVerdict.SAME and watch.see(11) is RunVerdict.OVER
    backlog = RunWatch()
    backlog.see(1)
    backlog.see(2)  # the sim restarted: run 1's messages still come in
    verdicts = [backlog.see(r) for _ in range(3 * REVIVE_AFTER) for r in (1, 2)]
    assert set(verdicts[0::2]) == {RunVerdict.OVER} and backlog.current == 2


def test_the_controller_starts_a_new_run_afresh_and_drops_the_old_one_s_leftovers(
    ctx, pipeline_frames
) -> None:
    """The sim dies after frame 4 and comes back: the new run's frame 0 is answered (it was
    taken for a frame paired already, and a lockstep loop stalled for good), by a controller
    with nothing of the run before; a message of the old run still in flight is dropped."""
    from services.controller.node import ControllerService

    service = ControllerService(ctx)  # type: ignore[arg-type]
    try:
        twists = published(service)
        keys = ctx.keys
        feed(service, ctx, pipeline_frames[:5], other="features")
        assert [t.header.frame_seq for t in twists] == [0, 1, 2, 3, 4]
        assert {t.header.run for t in twists} == {RUN_A}
        before = service.controller
        first = pipeline_frames[0]
        service.on_event(keys.joint_state, in_run(first.joints, RUN_B))
        service.on_event(keys.features, in_run(first.features, RUN_B))
        assert [t.header.frame_seq for t in twists] == [0, 1, 2, 3, 4, 0]
        assert twists[-1].header.run == RUN_B
        assert service.controller is not before  # servoing afresh
        # The same twist as the run's first frame had: the state of the run before is gone.
        assert twists[-1].linear_m_s == twists[0].linear_m_s
        late = in_run(pipeline_frames[5].features, RUN_A)
        service.on_event(keys.features, late)
        service.on_event(keys.joint_state, in_run(pipeline_frames[5].joints, RUN_A))
        assert len(twists) == 6 and service.node.received[keys.features].dropped == 1
    finally:
        service.node.close()


def test_actuation_ramps_a_new_run_from_rest(ctx, pipeline_frames) -> None:
    """After the sim restarted, the first command comes from rest (a fresh limiter), not from
    the last command of the run before with no time base (sim time began again)."""
    from services.actuation.node import ActuationService

    def commands(service, runs: list[int]) -> list[JointVelocityCommand]:
        sent = published(service)
        for run in runs:
            for f in pipeline_frames[:4] if run == RUN_A else pipeline_frames[:1]:
                service.on_event(ctx.keys.joint_state, in_run(f.joints, run))
                service.on_event(ctx.keys.twist, in_run(f.twist, run))
        return sent

    restarted = ActuationService(ctx)  # type: ignore[arg-type]
    fresh = ActuationService(ctx)  # type: ignore[arg-type]
    try:
        after_restart = commands(restarted, [RUN_A, RUN_B])
        from_scratch = commands(fresh, [RUN_B])
        assert [c.header.frame_seq for c in after_restart] == [0, 1, 2, 3, 0]
        assert after_restart[-1].header.run == RUN_B
        assert after_restart[-1].velocity_rad_s == from_scratch[-1].velocity_rad_s
        assert np.any(after_restart[3].velocity_rad_s)  # moving when the sim died
        # A twist and a joint state of the run before, still in flight: dropped, counted,
        # nothing sent for them and the new run's limiter untouched.
        limiter, sent_before = restarted.limiter, len(after_restart)
        restarted.on_event(ctx.keys.joint_state, in_run(pipeline_frames[1].joints, RUN_A))
        restarted.on_event(ctx.keys.twist, in_run(pipeline_frames[1].twist, RUN_A))
        assert len(after_restart) == sent_before and restarted.limiter is limiter
        received = restarted.node.received
        assert received[ctx.keys.twist].dropped == 1
        assert received[ctx.keys.joint_state].dropped == 1
    finally:
        restarted.node.close()
        fresh.node.close()


def test_vision_answers_a_resend_again_and_forgets_a_run_that_is_over(ctx, pipeline_frames) -> None:
    """A lockstep resend of the frame vision measured last gets the same features, its tracker
    not stepped a second time on it (which made lockstep runs differ); a new run starts with a
    fresh tracker, and a frame of the run before, still in flight, is dropped."""
    from services.vision.node import VisionService

    service = VisionService(ctx)  # type: ignore[arg-type]
    try:
        sent = published(service)
        rgb = ctx.keys.rgb
        for f in pipeline_frames[:3]:
            service.on_event(rgb, in_run(f.rgb, RUN_A))
        assert [m.header.frame_seq for m in sent] == [0, 1, 2]
        tracker = service.tracker
        service.on_event(rgb, in_run(pipeline_frames[2].rgb, RUN_A))  # resent
        assert sent[-1] is sent[-2] and service.tracker is tracker
        service.on_event(rgb, in_run(pipeline_frames[0].rgb, RUN_B))
        assert service.tracker is not tracker and sent[-1].header.run == RUN_B
        assert sent[-1].hand == sent[0].hand and sent[-1].target == sent[0].target
        service.on_event(rgb, in_run(pipeline_frames[3].rgb, RUN_A))
        assert len(sent) == 5 and service.node.received[rgb].dropped == 1
    finally:
        service.node.close()


def test_the_sim_applies_commands_of_its_own_run_and_stops_of_any() -> None:
    from services.sim.node import SimService

    sim = SimpleNamespace(run_id=RUN_B)

    def command(run: int, frame_seq: int) -> JointVelocityCommand:
        header = Header(seq=0, sim_time_s=0.0, send_time_s=1.0, frame_seq=frame_seq, run=run)
        return JointVelocityCommand(header=header, velocity_rad_s=[0.1] * 6, reason="track")

    assert SimService.answers(sim, command(RUN_B, 3), 3)  # type: ignore[arg-type]
    assert not SimService.answers(sim, command(RUN_A, 3), 3)  # type: ignore[arg-type]
    assert not SimService.answers(sim, command(RUN_B, 2), 3)  # type: ignore[arg-type]
    assert SimService.of_this_run(sim, command(RUN_B, 7))  # type: ignore[arg-type]
    assert not SimService.of_this_run(sim, command(RUN_A, 7))  # type: ignore[arg-type]
    assert SimService.of_this_run(sim, command(RUN_A, -1))  # type: ignore[arg-type]  # a stop


def test_actuation_frozen_past_its_deadman_ramps_up_from_rest(ctx, pipeline_frames) -> None:
    """Realtime: actuation frozen (SIGSTOP) for longer than its deadman cannot send the stop,
    and the sim's watchdog stops the motors instead. On resume its first command must ramp from
    rest over a camera period, not jump back to the speed it last commanded (the acceleration
    limit broken), nor stay at rest (twists that came that far apart never moved the arm)."""
    from common.runtime import parse_overrides
    from services.actuation.node import ActuationService

    ctx.scenario = load_scenario(None, parse_overrides(["run.clock='realtime'"]))
    service = ActuationService(ctx)  # type: ignore[arg-type]
    try:
        sent = published(service)
        feed(service, ctx, pipeline_frames[:5])
        assert np.any(sent[3].velocity_rad_s)  # moving
        assert service.last_valid_twist_s is not None
        service.last_valid_twist_s -= 1.0  # a second frozen: the deadman's time, unsent
        last = pipeline_frames[5]
        assert last.twist.valid
        service.on_event(ctx.keys.joint_state, in_run(last.joints, RUN_A))
        service.on_event(ctx.keys.twist, in_run(last.twist, RUN_A))
        resumed = np.abs(sent[-1].velocity_rad_s)
        ramp = ctx.scenario.actuation.max_joint_acceleration_rad_s2 * ctx.scenario.frame_period_s
        assert sent[-1].header.frame_seq == 5 and 0 < resumed.max() <= ramp * (1 + 1e-9)
        assert resumed.max() < np.abs(sent[3].velocity_rad_s).max()
        # Every twist after such a gap (a render far slower than the deadman): the arm moves.
        for f in pipeline_frames[6:10]:
            service.last_valid_twist_s -= 1.0
            service.on_event(ctx.keys.joint_state, in_run(f.joints, RUN_A))
            service.on_event(ctx.keys.twist, in_run(f.twist, RUN_A))
            assert np.any(sent[-1].velocity_rad_s), f.twist.header.frame_seq
    finally:
        service.node.close()
