"""The eye-to-hand interaction model against the renderer.

For small joint motions dq, the predicted feature motion ``ds = −L(s, Z) · V_cam`` with
``V_cam`` the hand twist ``J(q)·dq`` carried into the camera frame must match what the vision
measures on the rendered images within 5 %. The same holds for the 3-D corner points of the
points3d strategy: ``dP = J(P) · V_cam`` with ``J`` the stacked ``[I₃  -[P]×]``.
"""

from __future__ import annotations

import numpy as np

from common import kinematics as kin
from common.camera import pixel_to_normalized
from services.controller.interaction import (
    interaction_matrix,
    point_feature_jacobian,
)
from services.controller.twist import twist_matrix_base_ee_to_cam
from services.vision.measurement import measure_markers


def predicted_px(dq, jac, p_ee, l_s, t_base_cam, k) -> np.ndarray:
    """Corner displacements (4×2 px) the model predicts for a joint motion dq."""
    v_cam = twist_matrix_base_ee_to_cam(t_base_cam, p_ee) @ (jac @ dq)
    ds = (-l_s @ v_cam).reshape(4, 2)
    return ds * np.array([k.fx_px, k.fy_px])


def test_predicted_feature_motion_matches_the_rendered_one(world, scenario) -> None:
    k = world.intrinsics
    t_base_cam = scenario.camera.pose()
    rng = np.random.default_rng(42)
    q0 = np.array(scenario.robot.q0)
    ratios = []
    for _ in range(8):
        q = q0 + rng.normal(scale=0.05, size=6)
        world.reset(q)
        rgb, depth = world.render()
        before = measure_markers(rgb, depth, k, scenario.vision)["hand"]
        assert before.visible, before.reason
        jac = kin.geometric_jacobian(q)
        p_ee = kin.forward_kinematics(q)[:3, 3]
        xy = pixel_to_normalized(before.corners_px, k)
        l_s = interaction_matrix(xy, before.depth_m)
        direction = rng.normal(size=6)
        # Scale the motion so the corners move by about 12 px: far above corner noise,
        # small enough for the first-order model.
        unit = predicted_px(direction, jac, p_ee, l_s, t_base_cam, k)
        dq = direction * 12.0 / np.sqrt(np.mean(unit**2))
        world.reset(q + dq)
        rgb, depth = world.render()
        after = measure_markers(rgb, depth, k, scenario.vision, {"hand": before.corners_px})["hand"]
        assert after.visible, after.reason
        measured = after.corners_px - before.corners_px
        expected = predicted_px(dq, jac, p_ee, l_s, t_base_cam, k)
        ratios.append(np.linalg.norm(measured - expected) / np.linalg.norm(expected))
    worst = max(ratios)
    print(f"relative prediction error: median {np.median(ratios):.3%}, worst {worst:.3%}")
    assert worst < 0.05, f"relative errors {np.round(ratios, 4)}"


def predicted_points_m(dq, jac, p_ee, points_m, t_base_cam) -> np.ndarray:
    """Corner displacements (4×3 m, camera frame) the model predicts for a joint motion dq."""
    v_cam = twist_matrix_base_ee_to_cam(t_base_cam, p_ee) @ (jac @ dq)
    return (point_feature_jacobian(points_m) @ v_cam).reshape(4, 3)


def test_predicted_3d_point_motion_matches_the_rendered_one(world, scenario) -> None:
    """The points3d feature model on the corners vision back-projects with their plane-fitted
    depths. Central differences (q ± dq): moving the hand ~1 cm in depth takes a joint motion
    large enough that a one-sided difference carries a second-order term of up to 6 % (it
    quadruples when dq doubles, whatever its sign); the symmetric one cancels it."""
    k = world.intrinsics
    t_base_cam = scenario.camera.pose()
    rng = np.random.default_rng(42)  # the poses and directions of the test above
    q0 = np.array(scenario.robot.q0)
    ratios = []
    for _ in range(8):
        q = q0 + rng.normal(scale=0.05, size=6)
        world.reset(q)
        rgb, depth = world.render()
        before = measure_markers(rgb, depth, k, scenario.vision)["hand"]
        assert before.visible, before.reason
        jac = kin.geometric_jacobian(q)
        p_ee = kin.forward_kinematics(q)[:3, 3]
        direction = rng.normal(size=6)
        # About 1 cm per corner (the 12 px of the test above at 0.4 m): far above the corner
        # and plane-fit noise, small enough for the first-order model.
        unit = predicted_points_m(direction, jac, p_ee, before.points_m, t_base_cam)
        dq = direction * 0.01 / np.sqrt(np.mean(np.sum(unit**2, axis=1)))
        moved = []
        for sign in (1.0, -1.0):
            world.reset(q + sign * dq)
            rgb, depth = world.render()
            hand = measure_markers(rgb, depth, k, scenario.vision, {"hand": before.corners_px})
            assert hand["hand"].visible, hand["hand"].reason
            moved.append(hand["hand"].points_m)
        measured = (moved[0] - moved[1]) / 2
        expected = predicted_points_m(dq, jac, p_ee, before.points_m, t_base_cam)
        ratios.append(np.linalg.norm(measured - expected) / np.linalg.norm(expected))
    worst = max(ratios)
    print(
        f"3-D points: relative prediction error: median {np.median(ratios):.3%}, worst {worst:.3%}"
    )
    assert worst < 0.05, f"relative errors {np.round(ratios, 4)}"
