"""The goal's local stability under each law (services/controller/stability.py): the
eigenvalues of ``M L*`` against what the law does from a small displacement."""

from __future__ import annotations

import numpy as np
import pytest

from common.camera import CameraIntrinsics, pixel_to_normalized, project
from common.config import ConstantDepth, ControllerConfig, JacobianMode
from common.marker import Marker
from services.controller.arm import ArmReading
from services.controller.ibvs import IbvsController
from services.controller.interaction import constant_interaction_matrix
from services.controller.stability import constant_goal_stability, goal_stability
from tests.unit.test_ibvs import moved

K = CameraIntrinsics.from_fov(640, 480, 57.0)
SIZE_M = 0.06


def tilted_square(tilt_deg: float, centre_m: tuple[float, float, float] = (0.0, 0.0, 0.45)):
    """A square's corners (4×3, camera frame) turned ``tilt_deg`` about the camera's x axis:
    seen obliquely, its corners' depths differ."""
    h = SIZE_M / 2
    flat = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    t = np.radians(tilt_deg)
    rot = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    return flat @ rot.T + np.array(centre_m)


def seen(points_m: np.ndarray) -> Marker:
    return Marker.seen_at(points_m, K, np.zeros(4))


def error_after(goal_m: np.ndarray, depth: ConstantDepth, seconds: float) -> tuple[float, float]:
    """The constant law (λ = 1, 15 Hz) from a 2 mm / 0.01 rad displacement of the goal: the
    image error (px RMS) at the start and after ``seconds``."""
    m = np.linalg.pinv(constant_interaction_matrix(seen(goal_m), K, depth))
    s_star = pixel_to_normalized(project(goal_m, K), K)
    points = moved(goal_m, np.array([0.002, -0.001, 0.002, 0.01, -0.01, 0.005]), 1.0)
    errors = []
    for _ in range(int(seconds * 15)):
        e = (pixel_to_normalized(project(points, K), K) - s_star).reshape(-1)
        errors.append(float(np.sqrt(np.mean(e**2))) * K.fx_px)
        points = moved(points, m @ e, 1.0 / 15)
    return errors[0], errors[-1]


def test_a_law_that_inverts_the_goal_matrix_scores_one() -> None:
    goal = seen(tilted_square(50.0))
    assert constant_goal_stability(goal, K, ConstantDepth.PER_CORNER) == pytest.approx(1.0)
    facing = seen(tilted_square(0.0))  # every corner at one depth: one depth is exact
    assert constant_goal_stability(facing, K, ConstantDepth.SINGLE) == pytest.approx(1.0)
    rng = np.random.default_rng(3)
    m, l_goal = rng.normal(size=(6, 8)), rng.normal(size=(8, 6))
    assert goal_stability(np.linalg.pinv(l_goal), l_goal) == pytest.approx(1.0)
    assert goal_stability(-np.linalg.pinv(l_goal), l_goal) == pytest.approx(-1.0)
    assert goal_stability(m, l_goal) == pytest.approx(np.linalg.eigvals(m @ l_goal).real.min())


def test_one_depth_on_an_oblique_square_leaves_its_goal_as_the_eigenvalues_say() -> None:
    """Seen at 30° the single-depth matrix still holds the goal (a positive margin); at 50° an
    eigenvalue turns negative and the law drives the hand away; each corner's own depth holds
    it at 50° too."""
    mild, steep = tilted_square(30.0), tilted_square(50.0)
    assert 0.0 < constant_goal_stability(seen(mild), K, ConstantDepth.SINGLE) < 1.0
    assert constant_goal_stability(seen(steep), K, ConstantDepth.SINGLE) < 0.0
    start, end = error_after(mild, ConstantDepth.SINGLE, 20.0)
    assert end < 0.01 * start
    start, end = error_after(steep, ConstantDepth.SINGLE, 6.0)
    assert end > 10.0 * start
    start, end = error_after(steep, ConstantDepth.PER_CORNER, 10.0)
    assert end < 0.01 * start


@pytest.mark.parametrize("mode", list(JacobianMode))
def test_the_controller_reports_the_frozen_matrix_stability_for_constant_only(
    mode: JacobianMode,
) -> None:
    goal = tilted_square(50.0)
    target = seen(goal)  # no approach height: the goal is the target's own square
    hand = seen(moved(goal, np.array([0.01, 0.0, 0.0, 0.0, 0.0, 0.0]), 1.0))
    controller = IbvsController(ControllerConfig(mode=mode), np.eye(4))
    assert controller.goal_stability is None
    out = controller.step(hand, target, K, ArmReading(np.zeros(3)))
    assert out.valid
    if mode is JacobianMode.CONSTANT:
        assert controller.goal_stability == pytest.approx(
            constant_goal_stability(target, K, ConstantDepth.SINGLE)
        )
        assert controller.goal_stability < 0.0
    else:
        assert controller.goal_stability is None
