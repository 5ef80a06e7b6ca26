"""A campaign's runs counted per strategy: what campaign.md and the docs' tables both show."""

from __future__ import annotations

from deploy.experiments.campaign.tally import (
    STABILITY_HEADERS,
    TALLY_HEADERS,
    RunOutcome,
    StrategyTally,
    goal_stability_cells,
)

OUTCOMES = [
    RunOutcome("converged", 80, 1.0),
    RunOutcome("stuck (hand partial)", 400, 1.7),
    RunOutcome("joint limit", 900, 2.0),  # long and roundabout: no part of the medians
    RunOutcome("converged", 91, 1.5),
    RunOutcome("stuck (target partial)", 300, 1.5),
    RunOutcome("stuck (hand partial)", 350, 1.6),
    RunOutcome("refused at start"),  # never ran: not a run, counted under its own cause
]


def test_the_tally_counts_the_runs_and_leaves_refused_starts_out() -> None:
    tally = StrategyTally.tally("dynamic", OUTCOMES)
    assert (tally.label, tally.runs, tally.on_goal) == ("dynamic", 6, 2)
    assert tally.families == {"converged": 2, "stuck": 3, "joint limit": 1, "refused at start": 1}
    assert tally.family_count("stuck") == 3 and tally.family_count("collision") == 0
    # each failure's own cause, commonest first, ties in the order they came
    assert tally.failures == (
        ("stuck (hand partial)", 2),
        ("joint limit", 1),
        ("stuck (target partial)", 1),
    )


def test_the_medians_are_of_the_runs_on_goal_only() -> None:
    tally = StrategyTally.tally("dynamic", OUTCOMES)
    assert tally.median_frames == 85.5  # 80 and 91: the failures' 300–900 frames left out
    assert tally.median_path_ratio == 1.25
    # a run on goal without a path ratio counts for the frames only
    gapped = StrategyTally.tally("pmj", [*OUTCOMES, RunOutcome("converged", 95, None)])
    assert (gapped.median_frames, gapped.median_path_ratio) == (91.0, 1.25)


def test_the_cells_give_the_share_its_wilson_interval_and_the_medians() -> None:
    tally = StrategyTally.tally("dynamic", OUTCOMES)
    assert len(tally.cells()) == len(TALLY_HEADERS)
    # 2 of 6: 33.3%, and its Wilson interval (9.68–70.00% by the closed form)
    assert tally.cells() == ["dynamic", "6", "2", "33.3%", "9.7–70.0%", "85.5", "1.250"]


def test_a_strategy_without_runs_has_no_share_and_no_medians() -> None:
    half = StrategyTally.tally("mpj", [RunOutcome("converged")] * 23 + [RunOutcome("timeout")] * 57)
    assert half.success_cell() == "28.8%"  # 100 × 23 / 80 is 28.75, to even
    assert half.interval_cell() == "20.0–39.5%"
    refused = StrategyTally.tally("constant", [RunOutcome("refused at start")] * 3)
    assert (refused.runs, refused.on_goal, refused.family_count("refused at start")) == (0, 0, 3)
    assert refused.cells() == ["constant", "0", "0", "–", "–", "–", "–"]


def test_runs_are_split_by_whether_constants_frozen_matrix_holds_the_goal() -> None:
    stability = {"a": 1.0, "b": 0.4, "c": -1.5, "d": 0.0, "e": None, "f": 1.0}
    outcomes = [
        ("a", "converged"),
        ("b", "joint limit"),
        ("c", "converged"),
        ("d", "marker left the image"),  # 0: not held
        ("e", "converged"),  # no stability known: in neither column
        ("f", "refused at start"),  # never ran
    ]
    assert STABILITY_HEADERS[0] == "strategy"
    assert goal_stability_cells("constant", outcomes, stability) == [
        "constant",
        "1/2 (50.0%)",
        "1/2 (50.0%)",
    ]
    assert goal_stability_cells("pmj", [("a", "converged")], stability) == [
        "pmj",
        "1/1 (100.0%)",
        "–",
    ]
