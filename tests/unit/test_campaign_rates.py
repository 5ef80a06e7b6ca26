"""The Wilson score interval of a campaign's success rate."""

from __future__ import annotations

import math
from statistics import NormalDist

import pytest

from deploy.experiments.campaign.rates import interval_cell, wilson_interval


@pytest.mark.parametrize(
    ("successes", "runs", "low", "high"),
    [
        (50, 100, 0.40383, 0.59617),  # p = ½: centre ½, half-width z·√(¼/n + z²/4n²)/(1 + z²/n)
        (0, 10, 0.0, 0.27753),  # no success: the high bound is z² / (n + z²)
        (10, 10, 0.72247, 1.0),  # all: the low bound is n / (n + z²)
    ],
)
def test_wilson_interval_matches_its_closed_forms(
    successes: int, runs: int, low: float, high: float
) -> None:
    assert wilson_interval(successes, runs) == pytest.approx((low, high), abs=5e-6)


@pytest.mark.parametrize(("successes", "runs"), [(184, 191), (3, 7), (97, 100)])
def test_wilson_interval_is_the_score_interval_anywhere(successes: int, runs: int) -> None:
    """Centre (p + z²/2n)/(1 + z²/n), half-width z·√(p(1−p)/n + z²/4n²)/(1 + z²/n), z the
    normal's 97.5 % quantile: the general form, written out here apart from the code."""
    z, n, p = NormalDist().inv_cdf(0.975), runs, successes / runs
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    assert wilson_interval(successes, runs) == pytest.approx((centre - half, centre + half))


def test_the_interval_holds_the_rate_and_narrows_with_more_runs() -> None:
    for n in (20, 200, 2000):
        low, high = wilson_interval(int(0.97 * n), n)
        assert low < int(0.97 * n) / n < high
    widths = [high - low for low, high in (wilson_interval(97 * k, 100 * k) for k in (1, 4, 16))]
    assert widths[0] > widths[1] > widths[2]
    assert widths[0] / widths[2] == pytest.approx(4.0, rel=0.15)  # about 1/√n


@pytest.mark.parametrize(("successes", "runs"), [(1, 0), (-1, 5), (6, 5)])
def test_bad_counts_are_refused_with_the_field(successes: int, runs: int) -> None:
    with pytest.raises(ValueError, match=r"^(runs|successes): "):
        wilson_interval(successes, runs)


def test_the_table_cell() -> None:
    assert interval_cell(184, 191) == "92.6–98.2%"
    assert interval_cell(0, 0) == "–"
