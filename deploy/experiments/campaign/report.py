"""What a campaign writes besides compare's outputs: campaign.md (the starts, per strategy the
success rate and every cause, each failure with its detail), causes.json and starts.json."""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict

from pydantic import BaseModel

from deploy.experiments.campaign.causes import CAUSES, close_at_end, failure_cause
from deploy.experiments.campaign.starts import Distribution, Start
from deploy.experiments.campaign.tally import (
    ON_GOAL,
    STABILITY_HEADERS,
    TALLY_HEADERS,
    UNSTABLE_MEANS,
    RunOutcome,
    StrategyTally,
    goal_stability_cells,
    unstable_goals,
)
from deploy.experiments.compare.rows import ON_GOAL_M, CompareRow
from deploy.markdown import format_cell, markdown_table


class CampaignRow(BaseModel):
    """A run of the campaign and its cause, or a refused start (mode "", no result)."""

    start: str
    mode: str
    cause: str
    detail: str
    frames: int | None = None
    path_ratio: float | None = None


def campaign_rows(starts: Sequence[Start], rows: Sequence[CompareRow], modes: Sequence[str]):
    out = [
        CampaignRow(start=s.name, mode=m, cause="refused at start", detail=s.refused)
        for s in starts
        if s.refused
        for m in modes
    ]
    out += [
        CampaignRow(
            start=r.scenario,
            mode=r.mode,
            cause=failure_cause(r),
            detail=r.detail,
            frames=r.frames,
            path_ratio=r.path_ratio,
        )
        for r in rows
    ]
    return out


def taxonomy_markdown(
    starts: Sequence[Start], rows: Sequence[CompareRow], modes: Sequence[str], dist: Distribution
) -> str:
    """campaign.md: the starts (refused ones with their reasons), per strategy the success
    rate out of the non-refused starts, median frames and path ratio of the successes, the
    runs within 1 px and 5 mm at their end (:func:`close_at_end`), and the count of every
    cause."""
    crows = campaign_rows(starts, rows, modes)
    refused = [s for s in starts if s.refused]
    causes = [c for c in CAUSES if c != ON_GOAL]
    headers = [*TALLY_HEADERS, "< 1 px, < 5 mm at the end", *causes]
    body = []
    for mode in modes:
        outcomes = [RunOutcome(r.cause, r.frames, r.path_ratio) for r in crows if r.mode == mode]
        tally = StrategyTally.tally(mode, outcomes)
        close = sum(close_at_end(r) for r in rows if r.mode == mode)
        counts = [str(tally.family_count(c)) for c in causes]
        body.append([*tally.cells(), str(close), *counts])
    reasons = Counter(s.refused for s in refused)
    redraws: Counter[str] = Counter()
    for s in starts:
        redraws.update(s.redrawn)
    failures = [r for r in crows if r.cause not in ("converged", "refused at start")]
    parts = [
        "# Random-start campaign",
        "",
        f"{len(starts)} starts drawn (seed {dist.seed}; distribution in the repository, see "
        f"`deploy/campaigns/`): {len(refused)} refused at start "
        f"({format_cell(len(refused) / len(starts), 100.0, '.1f')}%), "
        f"{len(starts) - len(refused)} run with each of {len(modes)} strategies. Success: "
        f"converged (image error below the threshold) with the hand within "
        f"{1000 * ON_GOAL_M:g} mm of its goal (ground truth), out of the non-refused starts; "
        f"95% interval: its Wilson score interval. "
        f"Draws: {sum(s.draws for s in starts)} in all; drawn again (not in the distribution): "
        + (", ".join(f"{n} × {why}" for why, n in redraws.most_common()) or "none")
        + ".",
        "",
        "## Per strategy, and every run's cause",
        "",
        markdown_table(headers, body),
        "",
        "## Refused at start",
        "",
    ]
    parts += [f"- {n} × {reason}" for reason, n in reasons.most_common()] or ["None."]
    parts += ["", "## The constant strategy's frozen matrix at the goal", ""]
    parts += stability_section(starts, crows, modes)
    parts += ["", "## Runs that did not end on their goal", ""]
    parts += [f"- {r.start} · {r.mode}: **{r.cause}**; {r.detail}" for r in failures] or ["None."]
    return "\n".join(parts) + "\n"


def stability_section(
    starts: Sequence[Start], crows: Sequence[CampaignRow], modes: Sequence[str]
) -> list[str]:
    """campaign.md's lines on the goals the constant strategy's frozen matrix makes unstable
    (docs/campaign.md): how many, which, and every strategy's success on either kind."""
    stability = {s.name: s.constant_goal_stability for s in starts}
    unstable, known = unstable_goals(stability)
    body = [
        goal_stability_cells(mode, [(r.start, r.cause) for r in crows if r.mode == mode], stability)
        for mode in modes
    ]
    return [
        f"{len(unstable)} of the {known} goals run are unstable under the constant strategy's "
        f"frozen matrix ({UNSTABLE_MEANS}): " + (", ".join(unstable) or "none") + ".",
        "",
        markdown_table(list(STABILITY_HEADERS), body),
    ]


def starts_json(starts: Sequence[Start]) -> str:
    return json.dumps([asdict(s) for s in starts], indent=2) + "\n"
