"""How a run ends, and the result it is judged to: one pure logic for ``umay run`` (twists
arriving over Zenoh, :class:`deploy.launch.run.RunMonitor`) and the in-process run
(:mod:`deploy.launch.run_inprocess`), so both end on the same frame for the same reason.

A run ends at the first controller output (twist) that is converged once the scenario's events
are over, reaches the simulated timeout, reports a failed acquisition, closes a hold longer
than ``controller.stuck_after_s`` (sim time), or servoes an image error that has not fallen by
5 % below its best for ``controller.stall_after_s`` once the events are over (the law sits
in a local minimum: its twist has gone to zero, or it pushes against a limit, e.g. the
clearance above the object, which the twists then say; :mod:`services.controller.progress`):
the reasons
``converged``, ``timeout``, ``acquisition_failed``, ``stuck`` and ``stalled``. The result is
judged at that frame (deploy/launch/evaluate.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from common.config import EventAction, Scenario
from common.messages import EndEffectorTwist, SimTruth
from deploy.launch.evaluate import RunResult, summarize
from services.controller.ibvs import ACQUISITION_FAILED
from services.controller.progress import Progress, stall_detail

# A stall whose twists have all been lifted by the clearance this long (sim s) is held there.
HELD_BY_CLEARANCE_S = 1.0


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


@dataclass(frozen=True)
class HoldState:
    """What the end of a run is judged on besides the latest twist: the run of holding twists
    going on (``since_s`` None: the last twist moved), and while servoing, its progress."""

    since_s: float | None = None  # sim time the current run of holding twists began
    reason: str = ""  # of the latest holding twist
    progress: Progress = field(default_factory=Progress)
    lifted_since_s: float | None = None  # every twist since then lifted by the clearance


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
    # Servoing: not holding, not acquiring, the scenario's events over.
    servoing = tw.servoing and t >= limits.not_before_s
    progress = hold.progress.after(t, tw.error_px_rms, servoing)
    lifted_since = None
    if tw.valid and tw.lifted:
        lifted_since = t if hold.lifted_since_s is None else hold.lifted_since_s
    if tw.valid:
        hold = HoldState(progress=progress, lifted_since_s=lifted_since)
    else:
        hold = HoldState(t if hold.since_s is None else hold.since_s, tw.hold_reason, progress)
    if tw.converged and t >= limits.not_before_s:
        return hold, RunEnd("converged", "", seq)
    if t >= limits.timeout_s:
        return hold, RunEnd("timeout", timeout_detail(tw, limits.timeout_s), seq)
    if not tw.valid and tw.hold_reason.startswith(ACQUISITION_FAILED):
        return hold, RunEnd("acquisition_failed", f"{tw.hold_reason} (held at {t:.2f} s)", seq)
    if hold.since_s is not None and t - hold.since_s >= limits.stuck_after_s:
        return hold, RunEnd("stuck", stuck_detail(hold.reason, hold.since_s, t), seq)
    if progress.stalled(t, limits.stall_after_s):
        assert progress.best_px is not None
        held = lifted_since is not None and t - lifted_since >= HELD_BY_CLEARANCE_S
        detail = stall_detail(
            tw.error_px_rms, progress.best_px, progress.best_since_s, t,
            lifted_since if held else None,
        )  # fmt: skip
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
