"""Target acquisition from the domain study's starts that once never uncovered the target:
the hand over the target's right-hand part beside the image border, the orientation cue on.
Each is the published start (docs/domains/domains.json) run by the study's own lockstep
in-process pipeline, which the distributed one equals frame for frame
(integration/test_pipeline_vs_distributed.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from deploy.experiments.domains.run import run_inprocess
from deploy.experiments.domains.study import DomainStart, judge, load_study, plan_tasks

ROOT = Path(__file__).resolve().parents[2]


def published_start(name: str) -> DomainStart:
    study = json.loads((ROOT / "docs/domains/domains.json").read_text())
    return DomainStart(**next(s for s in study["starts"] if s["name"] == name))


@pytest.mark.parametrize(
    "name, what",
    [
        # up and right beside the right border: cut per image axis, the hand goes up
        ("c0003_d05", "a goal beside the border"),
        # a slide down and sideways ran the hand into the object's corner: tried last
        ("c0034_d10", "downward slides last"),
        # the forearm across the target's cue: the cue counted in the outline, then fitted
        ("c0018_d09", "the cue in a partly hidden outline"),
        # uncovered on the third attempt: each attempt at the clamp's speed, in time
        ("c0024_d09", "the acquisition's own gain"),
    ],
)
def test_the_hand_uncovers_the_target_then_converges(name: str, what: str) -> None:
    study, base_path = load_study(ROOT / "deploy/domains/study.toml")
    (task,) = plan_tasks(study, base_path, [published_start(name)], ["dynamic"])
    result = run_inprocess(task)
    record = judge(task, result)
    assert record.outcome == "converged", (what, record.cause, result.detail)
    assert result.marker_lost_s > 0.0, what  # the target was hidden at first
