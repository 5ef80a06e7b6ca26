"""How a run ends, and the result it is judged to: one pure logic for ``umay run`` (twists
arriving over Zenoh, :class:`deploy.launch.run.RunMonitor`) and the in-process run
(:mod:`deploy.launch.run_inprocess`), so both end on the same frame for the same reason.

A run ends at the first controller output (twist) that is converged once the scenario's events
are over, reaches the simulated timeout, reports a failed acquisition, closes a hold longer
than ``controller.stuck_after_s`` (sim time), or servoes an image error that has not fallen by
:data:`STALL_PROGRESS` for ``controller.stall_after_s`` once the events are over (the law sits
in a local minimum: its twist has gone to zero, or it pushes against a limit): the reasons
``converged``, ``timeout``, ``acquisition_failed``, ``stuck`` and ``stalled``. The result is
judged at that frame (deploy/evaluate.py).
"""

from __future__ import annotations

from dataclasses import dataclass

from common.config import EventAction, Scenario
from common.messages import EndEffectorTwist, SimTruth
from deploy.experiments.evaluate import RunResult, summarize
from services.controller.ibvs import ACQUISITION_FAILED


@dataclass(frozen=True)
class EndLimits:
    """A scenario's end conditions (sim seconds)."""

    timeout_s: float = 30.0
    not_before_s: float = 0.0  # convergence counts once the scenario's events are over
    stuck_after_s: float = 4.0  # a hold this long ends the run: stuck
    stall_after_s: float = 5.0  # servoing this long without progress ends the run: stalled

    @classmethod
    def of(cls, scenario: Scenario) -> EndLimits:
        return cls(
            timeout_s=scenario.run.timeout_s,
            not_before_s=scenario.events_end_s,
            stuck_after_s=scenario.controller.stuck_after_s,
            stall_after_s=scenario.controller.stall_after_s,
        )


# A fall of the image error by this fraction of its best level so far counts as progress.
STALL_PROGRESS = 0.05


@dataclass(frozen=True)
class HoldState:
    """What the end of a run is judged on besides the latest twist: the run of holding twists
    going on (``since_s`` None: the last twist moved), and while servoing, the image error's
    best level and since when it has not fallen by :data:`STALL_PROGRESS` below it."""

    since_s: float | None = None  # sim time the current run of holding twists began
    reason: str = ""  # of the latest holding twist
    best_px: float | None = None  # None: not servoing (holding, acquiring, events going on)
    best_since_s: float = 0.0


@dataclass(frozen=True)
class RunEnd:
    """Why a run ended, and the frame whose twist decided it."""

    reason: str  # converged / timeout / acquisition_failed / stuck / stalled
    detail: str  # "" when converged
    frame: int


def stuck_detail(hold_reason: str, since_s: float, now_s: float) -> str:
    """What a stuck run waited for and since when (sim time)."""
    return (
        f"held {now_s - since_s:.2f} s waiting for: {hold_reason or 'usable features'} "
        f"(holding since sim time {since_s:.2f} s)"
    )


def stall_detail(error_px: float, best_px: float, since_s: float, now_s: float) -> str:
    """What a stalled run's image error did, and since when (sim time)."""
    return (
        f"image error {error_px:.3f} px, not below {best_px:.3f} px by "
        f"{STALL_PROGRESS:.0%} for {now_s - since_s:.2f} s (since sim time {since_s:.2f} s): "
        "the law sits in a local minimum or against a limit"
    )


def timeout_detail(tw: EndEffectorTwist, timeout_s: float) -> str:
    """Why a run that timed out at twist ``tw`` had not converged."""
    if not tw.valid:
        return f"{timeout_s:g} s simulated; last holding: {tw.hold_reason}"
    if tw.hold_reason:  # acquiring: the twist carries no image error (it is not servoing)
        return f"{timeout_s:g} s simulated; still {tw.hold_reason}"
    return (
        f"{timeout_s:g} s simulated; still servoing, image error {tw.error_px_rms:.3f} px "
        "above the convergence threshold"
    )


def judge_twist(
    limits: EndLimits, hold: HoldState, tw: EndEffectorTwist
) -> tuple[HoldState, RunEnd | None]:
    """The hold state after twist ``tw`` (twists in frame order) and the run's end if ``tw``
    ends it."""
    t, seq = tw.header.sim_time_s, tw.header.frame_seq
    if not tw.valid:
        hold = HoldState(t if hold.since_s is None else hold.since_s, tw.hold_reason)
    elif tw.hold_reason or t < limits.not_before_s:  # acquiring, or the scenario's events
        hold = HoldState()
    else:
        e = tw.error_px_rms
        if hold.best_px is None or e < (1.0 - STALL_PROGRESS) * hold.best_px:
            hold = HoldState(best_px=e, best_since_s=t)
        elif hold.since_s is not None:
            hold = HoldState(best_px=hold.best_px, best_since_s=hold.best_since_s)
    if tw.converged and t >= limits.not_before_s:
        return hold, RunEnd("converged", "", seq)
    if t >= limits.timeout_s:
        return hold, RunEnd("timeout", timeout_detail(tw, limits.timeout_s), seq)
    if not tw.valid and tw.hold_reason.startswith(ACQUISITION_FAILED):
        return hold, RunEnd("acquisition_failed", f"{tw.hold_reason} (held at {t:.2f} s)", seq)
    if hold.since_s is not None and t - hold.since_s >= limits.stuck_after_s:
        return hold, RunEnd("stuck", stuck_detail(hold.reason, hold.since_s, t), seq)
    if hold.best_px is not None and t - hold.best_since_s >= limits.stall_after_s:
        detail = stall_detail(tw.error_px_rms, hold.best_px, hold.best_since_s, t)
        return hold, RunEnd("stalled", detail, seq)
    return hold, None


def run_result(
    scenario: Scenario,
    reason: str,
    detail: str,
    end: RunEnd | None,
    truths: dict[int, SimTruth],
    twists: dict[int, EndEffectorTwist],
    wall_time_s: float,
) -> RunResult:
    """The result of a run that ended for ``reason`` (``end``: the deciding twist's verdict,
    None when the run ended otherwise: wall-clock limit, a service exited, interrupted)."""
    if end is not None and end.reason == reason:
        last: int | None = end.frame
    else:
        last = max(twists) if twists else None
    if last is not None and last not in truths:
        last = max((k for k in truths if k <= last), default=None)
    return summarize(
        scenario.name,
        scenario.controller.mode.value,
        scenario.run.clock.value,
        reason,
        last,
        truths,
        twists,
        wall_time_s,
        scenario.target.approach_height_m,
        detail,
        period_s=1.0 / scenario.camera.rgb_hz,
        moving=[(e.at_s, e.end_s) for e in scenario.events if e.action is EventAction.MOVE_TARGET],
        image_size_px=(scenario.camera.width_px, scenario.camera.height_px),
        oriented_markers=scenario.marker.orientation_cue,
    )
