"""The law's twist under linear bounds, changed where the image notices it least. Pure.

Every strategy's twist ``u = M · e'`` (``e' = λ e − ṡ*``, :mod:`.interaction`) is the least-
squares solution of ``‖W u − e'‖`` for ``W = M⁺``: ``W`` is the law's own model of the
features' rate per twist (for constant, dynamic and PMJ the interaction matrix it inverts; for
MPJ and points3d the matrix whose pseudo-inverse its ``M`` is). A twist that must also meet
bounds ``A (u + Δ) ≥ b`` (the clearance above the object, :mod:`.clearance`) keeps that least
squares best with the ``Δ`` of least ``‖W Δ‖``: at the least-squares solution the cross term
vanishes, ``‖W (u + Δ) − e'‖² = ‖W u − e'‖² + ‖W Δ‖²``. The image error then falls as fast as
the law's model allows under the bounds, where lifting the twist straight up (the same bound
met with ``Δ`` along one direction) left constant's law, whose twist pressed down onto the
object, with nothing to act on.

A handful of bounds in six unknowns: solved on the dual by Hildreth's method (coordinate
ascent over ``y ≥ 0``, ``Δ = H⁻¹ Aᵀ y``, ``H = WᵀW`` and a small ridge, :data:`RIDGE`): exact
for one active bound, converged to well under the bounds' scale within :data:`SWEEPS` sweeps
otherwise; the caller makes up what is left short (:func:`.clearance.lift_then_nearest`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

SWEEPS = 100  # Hildreth sweeps over the bounds, at most
TOLERANCE = 1e-12  # a sweep that moves no dual variable by more than this (relative) ends it
# H = WᵀW + RIDGE · (trace(WᵀW) / 6) · I. A small marker's interaction matrix barely tells a
# sideways translation from the turn that moves its image the same way: without the ridge the
# correction could take a large pair of them that cancel in the image but not in the hand's
# motion. With it such a pair costs its size, and H stays invertible where W is rank-deficient.
RIDGE = 1e-6


def least_feature_change(
    twist: FloatArray,
    rows: FloatArray,
    bounds: FloatArray,
    feature_jacobian: FloatArray,
    sweeps: int = SWEEPS,
) -> tuple[FloatArray, bool]:
    """``twist + Δ`` with ``rows · (twist + Δ) ≥ bounds`` (as far as the sweeps get) and
    ``‖feature_jacobian · Δ‖`` least; and whether ``twist`` broke a bound. ``rows`` (m×6) and
    ``feature_jacobian`` (n×6) act on the same twist coordinates as ``twist``."""
    twist = np.asarray(twist, dtype=float)
    rows = np.asarray(rows, dtype=float)
    need = np.asarray(bounds, dtype=float) - rows @ twist
    if float(np.max(need)) <= 0.0:
        return twist.copy(), False
    w = np.asarray(feature_jacobian, dtype=float)
    h = w.T @ w
    h += RIDGE * np.trace(h) / 6.0 * np.eye(6)
    h_inv_rows = np.linalg.solve(h, rows.T)  # H⁻¹ Aᵀ, 6×m
    p = rows @ h_inv_rows  # the dual's matrix A H⁻¹ Aᵀ
    y = np.zeros(len(rows))
    for _ in range(sweeps):
        moved = 0.0
        for i in range(len(rows)):
            if p[i, i] > 0.0:
                step = max(-y[i], (need[i] - p[i] @ y) / p[i, i])
                y[i] += step
                moved = max(moved, abs(step))
        if moved <= TOLERANCE * max(1.0, float(np.max(y))):
            break  # one active bound: done after the second sweep
    return twist + h_inv_rows @ y, True
