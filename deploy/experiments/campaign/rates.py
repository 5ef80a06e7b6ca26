"""How sure a campaign's success rate is: the Wilson score interval. Pure.

A rate out of a couple of hundred runs moves by a run's half a percent: 184 of 191 and 188 of
191 are 96.3 % and 98.4 %, and neither alone says whether the strategy's true rate is above a
98 % goal. The Wilson interval (Wilson, 1927; Brown, Cai & DasGupta, 2001) is the usual one for
a binomial share near 0 or 1, where the normal approximation ``p ± z·√(p(1−p)/n)`` runs past 1
and is far too narrow: it is the set of rates the observed count would not reject at that
level.
"""

from __future__ import annotations

import math

Z_95 = 1.959963984540054  # the standard normal's 97.5 % quantile: a two-sided 95 % interval


def wilson_interval(successes: int, runs: int, z: float = Z_95) -> tuple[float, float]:
    """The Wilson score interval (low, high), as shares in [0, 1], of ``successes`` out of
    ``runs`` (``z``: the normal quantile of the level, 95 % two-sided by default)."""
    if runs < 1:
        raise ValueError(f"runs: at least 1, not {runs}")
    if not 0 <= successes <= runs:
        raise ValueError(f"successes: between 0 and runs ({runs}), not {successes}")
    p = successes / runs
    z2 = z * z
    centre = (p + z2 / (2 * runs)) / (1 + z2 / runs)
    half = z / (1 + z2 / runs) * math.sqrt(p * (1 - p) / runs + z2 / (4 * runs * runs))
    # At 0 or n the formula's bound is 0 or 1 in exact arithmetic: no rounding past it.
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == runs else min(1.0, centre + half)
    return low, high


def interval_cell(successes: int, runs: int) -> str:
    """``92.6–98.2%``: the 95 % Wilson interval of a table's success rate ("–" without runs)."""
    if runs < 1:
        return "–"
    low, high = wilson_interval(successes, runs)
    return f"{100.0 * low:.1f}–{100.0 * high:.1f}%"
