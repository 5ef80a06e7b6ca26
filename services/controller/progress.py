"""Whether servoing still makes progress: the image error's best level so far, and since when
it has not fallen :data:`STALL_PROGRESS` below it. An error that stops falling above the
convergence threshold means the law sits in a local minimum (its twist gone to zero with the
error not) or pushes against a limit. One logic for the end of ``umay run``
(:mod:`deploy.launch.run_end`) and the controller's status under ``umay up``."""

from __future__ import annotations

from dataclasses import dataclass

# A fall of the image error by this fraction of its best level so far counts as progress.
STALL_PROGRESS = 0.05


@dataclass(frozen=True)
class Progress:
    """The image error's best level while servoing (None: not servoing) and since when (sim s)."""

    best_px: float | None = None
    best_since_s: float = 0.0

    def after(self, t_s: float, error_px: float, servoing: bool) -> Progress:
        """The progress after a step at sim time ``t_s`` with image error ``error_px``; a step
        that is not servoing (holding, acquiring) restarts it."""
        if not servoing:
            return Progress()
        if self.best_px is None or error_px < (1.0 - STALL_PROGRESS) * self.best_px:
            return Progress(error_px, t_s)
        return self

    def stalled_for_s(self, now_s: float) -> float | None:
        """How long the error has not fallen below its best by STALL_PROGRESS (None: not
        servoing)."""
        return None if self.best_px is None else now_s - self.best_since_s

    def stalled(self, now_s: float, stall_after_s: float) -> bool:
        """Servoing for ``stall_after_s`` by ``now_s`` without progress."""
        stalled_s = self.stalled_for_s(now_s)
        return stalled_s is not None and stalled_s >= stall_after_s


# What a stall's detail says when the clearance holds the arm where the law would take the hand
# onto the object's top face or the forearm onto the object (the campaign's causes look for it).
HELD_BY_CLEARANCE = "the clearance holds the arm off the object"


def stall_detail(
    error_px: float,
    best_px: float,
    since_s: float,
    now_s: float,
    lifted_since_s: float | None = None,
) -> str:
    """What a stalled run's image error did, and since when (sim time); ``lifted_since_s``:
    every twist since then was corrected by the clearance (the law would take the hand onto
    the object's top face or the forearm onto the object), else None."""
    why = "the law sits in a local minimum or against a limit"
    if lifted_since_s is not None:
        why = (
            f"the law drives the arm towards the object and {HELD_BY_CLEARANCE} "
            f"(every twist corrected since sim time {lifted_since_s:.2f} s)"
        )
    return (
        f"image error {error_px:.3f} px, not below {best_px:.3f} px by "
        f"{STALL_PROGRESS:.0%} for {now_s - since_s:.2f} s (since sim time {since_s:.2f} s): "
        f"{why}"
    )


def describe_stall(error_px: float, progress: Progress, now_s: float, lifted: bool = False) -> str:
    """What a stalled controller's error does, for ``umay status``: ``stalled: image error
    22.7 px, not 5 % below its best 13.5 px for 6.0 s (since sim time 1.47 s)``, and, when its
    last twist was ``lifted``, that the clearance holds the arm off the object."""
    assert progress.best_px is not None
    since = progress.best_since_s
    held = f"; {HELD_BY_CLEARANCE}" if lifted else ""
    return (
        f"stalled: image error {error_px:.1f} px, not {STALL_PROGRESS:.0%} below its best "
        f"{progress.best_px:.1f} px for {now_s - since:.1f} s (since sim time {since:.2f} s)"
        f"{held}"
    )
