"""The law's twist under the clearance's bounds: changed where its features notice it least."""

from __future__ import annotations

import numpy as np
import pytest

from services.controller.clearance import Plane, clearance_bounds, lift_short
from services.controller.constrained import RIDGE, least_feature_change

FLOOR = Plane(np.zeros(3), np.array([0.0, 1.0, 0.0]))
BOX = np.array([[x, y, z] for x in (-0.04, 0.04) for y in (0.01, 0.035) for z in (-0.045, 0.045)])
EE = np.array([0.0, 0.05, 0.0])


def feature_jacobian(seed: int) -> np.ndarray:
    """An 8×6 matrix of full rank, scaled as an interaction matrix at about half a metre."""
    return np.random.default_rng(seed).normal(size=(8, 6)) * np.array([2, 2, 2, 1, 1, 1.0])


def test_a_twist_within_its_bounds_is_left_as_it_is() -> None:
    twist = np.array([0.01, 0.2, 0.0, 0.0, 0.0, 0.0])  # rising
    rows, bounds = clearance_bounds(BOX, EE, FLOOR, 0.002, 3.0)
    out, corrected = least_feature_change(twist, rows, bounds, feature_jacobian(0))
    assert not corrected and np.array_equal(out, twist)


def test_with_the_identity_one_bound_gives_the_nearest_twist() -> None:
    a = np.array([[0.0, 1.0, 0.0, 0.5, 0.0, 0.0]])
    twist = np.array([0.1, -0.3, 0.0, 0.0, 0.2, 0.0])
    out, corrected = least_feature_change(twist, a, np.array([0.0]), np.eye(6))
    need = 0.0 - a[0] @ twist
    assert corrected
    np.testing.assert_allclose(out, twist + need * a[0] / (a[0] @ a[0]), atol=1e-9)


def test_one_bound_is_met_exactly_at_the_least_change_of_the_image() -> None:
    """Closed form for one active bound: Δ = H⁻¹a · need / (aᵀH⁻¹a), H = WᵀW + the ridge."""
    w = feature_jacobian(1)
    a = np.array([0.0, 1.0, 0.0, 0.02, 0.0, -0.03])
    twist = np.array([0.0, -0.1, 0.02, 0.1, 0.0, 0.0])
    out, _ = least_feature_change(twist, a[None, :], np.array([-0.01]), w)
    h = w.T @ w
    h_inv_a = np.linalg.solve(h + RIDGE * np.trace(h) / 6 * np.eye(6), a)
    expected = twist + h_inv_a * (-0.01 - a @ twist) / (a @ h_inv_a)
    np.testing.assert_allclose(out, expected, rtol=1e-9, atol=1e-12)
    assert a @ out == pytest.approx(-0.01, abs=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_every_corner_is_kept_and_the_image_changes_less_than_by_lifting(seed: int) -> None:
    """A turn that dips an edge and a fall: all eight bounds hold; the law's least squares stays
    best (its residual grows by ‖W Δ‖² alone) and no feasible twist nearby changes the image
    less; lifting the twist straight up meets the same bounds at a larger change."""
    rng = np.random.default_rng(seed)
    w = feature_jacobian(seed)
    e = rng.normal(size=8) * 0.05
    twist = np.linalg.pinv(w) @ e + np.array([0.0, -0.2, 0.0, 0.0, 0.0, 1.5])  # dips, falls
    rows, bounds = clearance_bounds(BOX, EE, FLOOR, 0.002, 3.0)
    out, corrected = least_feature_change(twist, rows, bounds, w)
    assert corrected and np.all(rows @ out >= bounds - 1e-9)
    change = np.linalg.norm(w @ (out - twist))
    lifted, _ = lift_short(twist, rows, bounds, FLOOR.normal)
    assert np.all(rows @ lifted >= bounds - 1e-9)
    assert change < np.linalg.norm(w @ (lifted - twist))
    for _ in range(2000):
        near = out + rng.normal(size=6) * 1e-3
        if np.all(rows @ near >= bounds):
            assert np.linalg.norm(w @ (near - twist)) >= change - 1e-12


def test_the_laws_least_squares_stays_least_under_the_bounds() -> None:
    """u = W⁺ e' is the law's twist; u + Δ leaves ‖W(u + Δ) − e'‖² = ‖W u − e'‖² + ‖W Δ‖²."""
    w = feature_jacobian(7)
    e = np.random.default_rng(7).normal(size=8) * 0.05
    u = np.linalg.pinv(w) @ e
    rows, bounds = clearance_bounds(BOX, EE, FLOOR, 0.002, 3.0)
    out, _ = least_feature_change(u, rows, bounds - 0.5, w)  # a bound the twist breaks
    delta = out - u
    residual = np.linalg.norm(w @ out - e) ** 2
    assert residual == pytest.approx(
        np.linalg.norm(w @ u - e) ** 2 + np.linalg.norm(w @ delta) ** 2, rel=1e-9
    )
