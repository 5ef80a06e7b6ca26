"""A campaign's runs counted per strategy, and the table cells that show the counts. Pure.

campaign.md (:mod:`.report`, from the campaign's rows) and the docs' campaign tables
(:mod:`deploy.docs.campaign_tables`, from ``causes.json``) show the same figures per strategy:
runs, on goal, success, its Wilson interval, medians of the runs on goal, and the count of each
cause family. Both read them from one :class:`StrategyTally`, so that what is counted, and how a
cell writes it, is decided once.
"""

from __future__ import annotations

import statistics
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import NamedTuple

from deploy.experiments.campaign.causes import cause_family
from deploy.experiments.campaign.rates import interval_cell

ON_GOAL = "converged"  # the cause of a run that ended on its goal
REFUSED = "refused at start"  # the cause of a start the pre-launch check refused: not a run

# The columns every per-strategy table of a campaign begins with (:meth:`StrategyTally.cells`).
TALLY_HEADERS = (
    "strategy",
    "runs",
    "on goal",
    "success",
    "95% interval",
    "median frames",
    "median path ratio",
)


class RunOutcome(NamedTuple):
    """What the tally reads of one run or refused start: its cause, and its frames and path
    ratio where it ran (None where the run has none, or the start was refused)."""

    cause: str
    frames: int | None = None
    path_ratio: float | None = None


def _median(values: Iterable[float | int | None]) -> float | None:
    """The median of the values given (None where there are none)."""
    present = [float(v) for v in values if v is not None]
    return statistics.median(present) if present else None


@dataclass(frozen=True)
class StrategyTally:
    """One strategy's (or variant's) runs counted: ``runs`` (refused starts left out, as they
    never ran), ``on_goal`` among them, the median frames and path ratio of the runs on goal,
    ``families`` (the count of every cause family, refused starts included under
    :data:`REFUSED`) and ``failures`` (each cause of a run not on its goal with its count,
    commonest first; ties in the order the causes first came)."""

    label: str
    runs: int
    on_goal: int
    median_frames: float | None
    median_path_ratio: float | None
    families: Mapping[str, int]
    failures: tuple[tuple[str, int], ...]

    @classmethod
    def tally(cls, label: str, outcomes: Iterable[RunOutcome]) -> StrategyTally:
        """The tally of ``outcomes``, a strategy's runs and refused starts, labelled ``label``."""
        every = list(outcomes)
        ran = [o for o in every if o.cause != REFUSED]
        won = [o for o in ran if o.cause == ON_GOAL]
        return cls(
            label=label,
            runs=len(ran),
            on_goal=len(won),
            median_frames=_median(o.frames for o in won),
            median_path_ratio=_median(o.path_ratio for o in won),
            families=dict(Counter(cause_family(o.cause) for o in every)),
            failures=tuple(Counter(o.cause for o in ran if o.cause != ON_GOAL).most_common()),
        )

    def success_cell(self) -> str:
        """``96.3%``: the share of the runs on goal ("–" without any run)."""
        return f"{100.0 * self.on_goal / self.runs:.1f}%" if self.runs else "–"

    def interval_cell(self) -> str:
        """``94.2–97.6%``: the success's 95% Wilson interval ("–" without any run)."""
        return interval_cell(self.on_goal, self.runs)

    def median_cells(self) -> list[str]:
        """Median frames (83.5 between two runs) and median path ratio of the runs on goal
        ("–" without any)."""
        frames, ratio = self.median_frames, self.median_path_ratio
        return [
            "–" if frames is None else f"{frames:g}",
            "–" if ratio is None else f"{ratio:.3f}",
        ]

    def cells(self) -> list[str]:
        """The cells under :data:`TALLY_HEADERS`: label, runs, on goal, success, its interval,
        median frames and median path ratio."""
        counts = [self.label, str(self.runs), str(self.on_goal)]
        return [*counts, self.success_cell(), self.interval_cell(), *self.median_cells()]

    def family_count(self, family: str) -> int:
        """How many of the outcomes fell in the cause ``family`` (0 where none)."""
        return self.families.get(family, 0)


# What "unstable" means in the tables that split runs by it (campaign.md, docs/campaign.md).
UNSTABLE_MEANS = "an eigenvalue of `L_c⁺ L*` with a real part at or below 0, from the true geometry"
# The columns of the table that splits each strategy's runs by the constant strategy's
# stability at the start's goal (:func:`goal_stability_cells`).
STABILITY_HEADERS = (
    "strategy",
    "on goal, goals constant's matrix holds",
    "on goal, goals it leaves",
)


def goal_stability_cells(
    label: str, outcomes: Iterable[tuple[str, str]], stability: Mapping[str, float | None]
) -> list[str]:
    """A row under :data:`STABILITY_HEADERS`: ``label``, then the runs on goal out of those
    from starts whose goal the constant strategy's frozen matrix holds (``stability`` of the
    start above 0, :mod:`services.controller.stability`) and out of those whose goal it makes
    unstable. ``outcomes``: each run's start and cause; refused starts, and starts without a
    stability, are left out."""
    every = list(outcomes)
    cells = [label]
    for holds in (True, False):
        own = [
            cause
            for start, cause in every
            if cause != REFUSED
            and (value := stability.get(start)) is not None
            and (value > 0.0) == holds
        ]
        won = sum(cause == ON_GOAL for cause in own)
        cells.append(f"{won}/{len(own)} ({100.0 * won / len(own):.1f}%)" if own else "–")
    return cells


def unstable_goals(stability: Mapping[str, float | None]) -> tuple[list[str], int]:
    """The starts whose goal the constant strategy's frozen matrix makes unstable (a stability
    at or below 0), in order, and how many starts have a stability at all (those run)."""
    unstable = [start for start, value in stability.items() if value is not None and value <= 0]
    return unstable, sum(value is not None for value in stability.values())
