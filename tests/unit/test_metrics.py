"""common.metrics: the percentile helper the services use instead of np.percentile."""

from __future__ import annotations

import numpy as np
import pytest

from common.metrics import DurationMeter, percentile


@pytest.mark.parametrize("n", [1, 2, 3, 7, 100, 1001])
def test_percentile_is_numpys_to_the_bit(n: int) -> None:
    rng = np.random.default_rng(n)
    for scale in (1e-3, 1.0, 1e3):
        values = rng.normal(size=n) * scale
        for q in (0.0, 1.0, 5.0, 25.0, 50.0, 62.5, 99.0, 99.9, 100.0):
            assert percentile(values, q) == float(np.percentile(values, q)), (n, scale, q)


def test_percentile_leaves_its_input_alone_and_refuses_nonsense() -> None:
    values = np.array([3.0, 1.0, 2.0])
    assert percentile(values, 50.0) == 2.0
    assert values.tolist() == [3.0, 1.0, 2.0]
    with pytest.raises(ValueError):
        percentile(np.array([]), 50.0)
    with pytest.raises(ValueError):
        percentile(values, 101.0)


def test_duration_meter_reports_p50_and_p99() -> None:
    meter = DurationMeter(size=100)
    assert meter.percentiles() == (None, None)
    for ms in range(1, 201):  # only the last 100 (101..200) are kept
        meter.add(float(ms))
    p50, p99 = meter.percentiles()
    assert p50 == pytest.approx(150.5)
    assert p99 == pytest.approx(199.01)
