"""No silent holds: a run that holds too long ends as stuck, naming what it waited for."""

from __future__ import annotations

from dataclasses import dataclass

from common.codec import encode
from common.messages import EndEffectorTwist, Header
from deploy.launch.evaluate import summarize
from deploy.launch.run import RunMonitor, twist_phase
from deploy.launch.run_end import EndLimits, stuck_detail
from services.controller.progress import (
    HELD_BY_CLEARANCE,
    Progress,
    describe_stall,
    stall_detail,
)

PERIOD_S = 1 / 30


@dataclass
class Payload:
    data: bytes

    def to_bytes(self) -> bytes:
        return self.data


@dataclass
class Sample:
    payload: Payload


def twist(
    seq: int, valid: bool, reason: str = "", error_px: float = 3.0, lifted: bool = False
) -> EndEffectorTwist:
    header = Header(seq=seq, sim_time_s=seq * PERIOD_S, send_time_s=0.0, frame_seq=seq)
    return EndEffectorTwist(
        header=header,
        linear_m_s=[0.01 if valid else 0.0, 0.0, 0.0],
        angular_rad_s=[0.0, 0.0, 0.0],
        valid=valid,
        hold_reason=reason,
        mode="dynamic",
        error_px_rms=error_px if valid else 0.0,
        converged=False,
        lifted=lifted,
    )


def feed(monitor: RunMonitor, twists: list[EndEffectorTwist]) -> None:
    for tw in twists:
        monitor.on_twist(Sample(Payload(encode(tw))))


def test_a_hold_longer_than_stuck_after_ends_the_run_naming_what_and_since_when() -> None:
    monitor = RunMonitor(limits=EndLimits(timeout_s=30.0, stuck_after_s=4.0))
    feed(monitor, [twist(i, True) for i in range(30)])  # servoing for 1 s
    feed(monitor, [twist(i, False, "target partial") for i in range(30, 30 + 4 * 30)])
    assert not monitor.decided.is_set()  # 3.97 s of holding: not yet
    feed(monitor, [twist(150, False, "target partial")])
    assert monitor.decided.is_set() and monitor.ended == "stuck"
    assert monitor.ended_frame == 150
    assert monitor.ended_detail == stuck_detail("target partial", 1.0, 5.0)
    assert "waiting for: target partial" in monitor.ended_detail
    assert "since sim time 1.00 s" in monitor.ended_detail


def test_motion_between_holds_restarts_the_count() -> None:
    monitor = RunMonitor(limits=EndLimits(timeout_s=30.0, stuck_after_s=1.0))
    for start in range(0, 300, 40):  # 0.9 s holding, then one frame of motion, again and again
        feed(monitor, [twist(start + i, False, "hand lost") for i in range(27)])
        feed(monitor, [twist(start + i, True) for i in range(27, 40)])
    assert not monitor.decided.is_set()


def test_a_failed_acquisition_ends_the_run_at_once() -> None:
    monitor = RunMonitor(limits=EndLimits(timeout_s=30.0, stuck_after_s=4.0))
    reason = "acquisition failed: target partial after 4 attempt(s) from 0.53 s"
    feed(monitor, [twist(0, True), twist(1, False, reason)])
    assert monitor.ended == "acquisition_failed" and reason in monitor.ended_detail


def test_servoing_without_progress_ends_the_run_as_stalled_naming_the_best_and_since_when() -> None:
    monitor = RunMonitor(limits=EndLimits(timeout_s=30.0, stall_after_s=5.0))
    # falls from 40 px to 20 px over the first second, then creeps (under 5 % of 20 px)
    feed(monitor, [twist(i, True, error_px=40.0 - 20.0 * i / 30) for i in range(31)])
    creep = [twist(i, True, error_px=20.0 - 0.5 * (i - 30) / 150) for i in range(31, 180)]
    feed(monitor, creep)
    assert not monitor.decided.is_set()  # 4.97 s since its best: not yet
    feed(monitor, [twist(180, True, error_px=19.6)])
    assert monitor.decided.is_set() and monitor.ended == "stalled"
    assert monitor.ended_frame == 180
    assert monitor.ended_detail == stall_detail(19.6, 20.0, 1.0, 6.0)
    assert "since sim time 1.00 s" in monitor.ended_detail


def test_a_stall_held_by_the_clearance_says_so_and_since_when() -> None:
    """Twists lifted by the clearance for the last second and more: the law would lower the
    hand onto the object, and the detail says the clearance holds it; lifted only for the last
    half second, it does not."""
    for lifted_from, held in ((120, True), (166, False)):
        monitor = RunMonitor(limits=EndLimits(timeout_s=30.0, stall_after_s=5.0))
        falling = [twist(i, True, error_px=40.0 - 20.0 * i / 30) for i in range(31)]
        stalled = [twist(i, True, error_px=20.0, lifted=i >= lifted_from) for i in range(31, 181)]
        feed(monitor, falling + stalled)
        assert monitor.ended == "stalled" and monitor.ended_frame == 180
        since = lifted_from * PERIOD_S if held else None
        assert monitor.ended_detail == stall_detail(20.0, 20.0, 1.0, 6.0, since)
        assert (HELD_BY_CLEARANCE in monitor.ended_detail) is held
    assert "every twist corrected since sim time 4.00 s" in stall_detail(20.0, 20.0, 1.0, 6.0, 4.0)


def test_a_slow_steady_fall_is_progress_and_never_stalls() -> None:
    # 6 % every 5 s: a little faster than the 5 % in stall_after_s that counts as progress
    monitor = RunMonitor(limits=EndLimits(timeout_s=30.0, stall_after_s=5.0))
    feed(monitor, [twist(i, True, error_px=30.0 * 0.94 ** (i / 150)) for i in range(29 * 30)])
    assert not monitor.decided.is_set()


def test_acquiring_and_the_scenario_events_do_not_count_as_stalled() -> None:
    acquiring = "acquiring: target partial, attempt 1/4"
    monitor = RunMonitor(limits=EndLimits(timeout_s=30.0, stall_after_s=1.0, not_before_s=3.0))
    feed(monitor, [twist(i, True, error_px=5.0) for i in range(90)])  # events go on: tracking
    feed(monitor, [twist(i, True, acquiring, error_px=0.0) for i in range(90, 150)])
    assert not monitor.decided.is_set()
    feed(monitor, [twist(i, True, error_px=5.0) for i in range(150, 181)])  # servoing: 1 s
    assert monitor.ended == "stalled" and monitor.ended_frame == 180


def test_the_live_line_names_the_phase() -> None:
    assert twist_phase(twist(0, True)) == "servoing"
    assert twist_phase(twist(0, False, "target partial")) == "holding: target partial"
    acquiring = "acquiring: target partial, attempt 1/4"
    assert twist_phase(twist(0, True, acquiring)) == acquiring
    lifted = twist_phase(twist(0, True, lifted=True))
    assert lifted == "servoing, lifted above the object"


def test_a_result_that_did_not_converge_must_say_why() -> None:
    try:
        summarize("s", "dynamic", "lockstep", "timeout", None, {}, {}, 1.0, 0.03)
    except ValueError as exc:
        assert "detail" in str(exc)
    else:
        raise AssertionError("a timeout without a detail was accepted")
    ok = summarize("s", "dynamic", "lockstep", "timeout", None, {}, {}, 1.0, 0.03, "why")
    assert ok.detail == "why" and not ok.converged


def test_status_says_what_a_hold_waits_for_and_for_how_long() -> None:
    from common.config import ControllerConfig
    from services.controller.ibvs import describe_hold

    cfg = ControllerConfig(stuck_after_s=4.0)
    assert describe_hold("target partial", 1.0, 3.0, cfg) == (
        "holding: target partial (for 2.0 s, since sim time 1.00 s)"
    )
    assert describe_hold("hand lost", 1.0, 6.5, cfg) == (
        "holding: hand lost (stuck, for 5.5 s, since sim time 1.00 s)"
    )


def test_progress_restarts_off_servoing_and_status_describes_a_stall() -> None:
    p = Progress().after(0.0, 20.0, True).after(1.0, 19.5, True)  # under 5 % below 20 px
    assert (p.best_px, p.best_since_s, p.stalled_for_s(6.0)) == (20.0, 0.0, 6.0)
    assert p.after(6.5, 18.9, True).best_since_s == 6.5  # 5.5 % below: progress
    assert p.after(2.0, 19.0, False) == Progress() and Progress().stalled_for_s(3.0) is None
    assert describe_stall(19.4, p, 6.0) == (
        "stalled: image error 19.4 px, not 5% below its best 20.0 px for 6.0 s "
        "(since sim time 0.00 s)"
    )
    assert describe_stall(19.4, p, 6.0, lifted=True).endswith(
        "(since sim time 0.00 s); the clearance holds the arm off the object"
    )
