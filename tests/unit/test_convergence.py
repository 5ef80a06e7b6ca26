"""Convergence's window (services/controller/convergence.py): the averaged error under the
threshold, or a plateau under a pixel held long enough."""

from __future__ import annotations

import numpy as np

from common.config import ControllerConfig
from services.controller.convergence import ConvergenceWindow

CFG = ControllerConfig(converged_px=0.25, converged_frames=5, plateau_px=1.0, plateau_s=1.5)


def test_settled_once_the_window_is_full_and_its_mean_is_under_the_threshold() -> None:
    window = ConvergenceWindow()
    wobble = [np.full(8, 0.05 + 0.35 * (-1) ** i) for i in range(5)]  # each frame over 0.25 px
    for i, error in enumerate(wobble):
        assert not window.settled(i / 30, CFG)
        window.add(error, CFG)
    assert window.settled(5 / 30, CFG)  # their mean, 0.12 px, is under 0.25 px
    window.add(np.full(8, 3.0), CFG)
    assert not window.settled(6 / 30, CFG) and len(window.errors_px) == 5


def test_a_plateau_under_a_pixel_settles_after_plateau_s_and_progress_restarts_it() -> None:
    window = ConvergenceWindow()
    t = 0.0
    for _ in range(5):
        window.add(np.full(8, 0.6), CFG)
    while not window.settled(t, CFG):
        t += 1 / 30
        assert t < 2.0
    assert t >= CFG.plateau_s
    window.clear()
    assert window.plateau is None and not window.settled(t, CFG)
    for _ in range(5):
        window.add(np.full(8, 0.6), CFG)
    assert not window.settled(t, CFG)  # a new plateau, from now
    for _ in range(5):
        window.add(np.full(8, 0.4), CFG)  # fell by more than 5 %: progress
    assert not window.settled(t + 1.0, CFG)
    assert window.plateau is not None and window.plateau.since_s == t + 1.0
