"""The project's DH kinematics against pybullet on the generated URDF, and against itself."""

from __future__ import annotations

import numpy as np
import pybullet

from common import kinematics as kin


def random_configurations(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(kin.JOINT_LOWER_RAD, kin.JOINT_UPPER_RAD, size=(n, kin.N_JOINTS))


def test_table_1_1_at_zero_folds_the_forearm_back() -> None:
    poses = kin.frame_transforms(np.zeros(6))
    elbow, wrist = poses[3][:3, 3], poses[5][:3, 3]
    assert np.linalg.norm(elbow) == np.sqrt(0.005**2 + 0.020**2 + 0.264**2)
    # The forearm (212 mm) comes back along the upper arm: the wrist is 52 mm out.
    np.testing.assert_allclose(wrist, [0.005, 0.020, 0.052], atol=1e-12)


def test_fk_and_jacobian_match_pybullet_on_100_configurations(world) -> None:
    c, robot = world.client, world.robot
    worst_pos, worst_rot, worst_jac = 0.0, 0.0, 0.0
    for q in random_configurations(100):
        world.reset(q)
        ours = kin.forward_kinematics(q)
        theirs = world.ee_pose()
        worst_pos = max(worst_pos, float(np.linalg.norm(ours[:3, 3] - theirs[:3, 3])))
        worst_rot = max(worst_rot, kin.rotation_error_rad(ours[:3, :3], theirs[:3, :3]))
        lin, ang = c.calculateJacobian(
            robot, world.ee_link, [0.0, 0.0, 0.0], q.tolist(), [0.0] * 6, [0.0] * 6
        )
        jac_pb = np.vstack([np.array(lin), np.array(ang)])
        worst_jac = max(worst_jac, float(np.abs(kin.geometric_jacobian(q) - jac_pb).max()))
    assert worst_pos < 1e-6, f"worst FK position error {worst_pos:.2e} m"
    assert worst_rot < 1e-6, f"worst FK rotation error {worst_rot:.2e} rad"
    assert worst_jac < 1e-6, f"worst Jacobian entry error {worst_jac:.2e}"
    assert pybullet.getNumJoints(robot, physicsClientId=c._client) == 6


def test_jacobian_matches_finite_differences() -> None:
    eps = 1e-7
    for q in random_configurations(20, seed=1):
        jac = kin.geometric_jacobian(q)
        t0 = kin.forward_kinematics(q)
        for i in range(kin.N_JOINTS):
            dq = np.zeros(6)
            dq[i] = eps
            t1 = kin.forward_kinematics(q + dq)
            np.testing.assert_allclose((t1[:3, 3] - t0[:3, 3]) / eps, jac[:3, i], atol=1e-5)
            w = kin.rotation_log(t0[:3, :3].T @ t1[:3, :3]) / eps
            np.testing.assert_allclose(t0[:3, :3] @ w, jac[3:, i], atol=1e-5)


def test_inverse_kinematics_reaches_a_reachable_pose() -> None:
    q_true = random_configurations(1, seed=3)[0] * 0.5
    goal = kin.forward_kinematics(q_true) @ kin.hand_marker_in_ee()
    seed = q_true + 0.2  # (q = 0 itself is singular: joints 1 and 3 align)
    _, pos_err, rot_err = kin.inverse_kinematics(goal, seed, kin.hand_marker_in_ee())
    assert pos_err < 1e-6 and rot_err < 1e-6


def test_cross_is_np_cross_bit_for_bit() -> None:
    # The controller's twist transform and s* normal use it: results must not move at all.
    rng = np.random.default_rng(7)
    for _ in range(2000):
        a = rng.normal(size=3) * 10 ** rng.uniform(-6, 6)
        b = rng.normal(size=3) * 10 ** rng.uniform(-6, 6)
        assert np.array_equal(kin.cross(a, b), np.cross(a, b))
    assert np.array_equal(kin.cross(np.array([1.0, 0, 0]), np.array([0, 1.0, 0])), [0, 0, 1.0])


def test_quaternion_round_trip_in_every_branch_and_agrees_with_pybullet() -> None:
    # A turn of 0.3 rad has a positive trace; turns of π - 0.2 about axes near x, y and z make
    # the largest diagonal entry pick each of the three other branches of Shepperd's method.
    rng = np.random.default_rng(4)
    near_axes = [np.eye(3)[i] + 0.3 * rng.normal(size=3) for i in range(3)]
    turns = [(rng.normal(size=3), 0.3)] + [(axis, np.pi - 0.2) for axis in near_axes]
    for axis, angle in turns:
        axis = axis / np.linalg.norm(axis)
        k = kin.skew(axis)
        r = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k  # Rodrigues
        q = kin.quaternion_xyzw(r)
        assert abs(np.linalg.norm(q) - 1.0) < 1e-12
        assert np.allclose(kin.rotation_from_quaternion(*q), r, atol=1e-12)
        m = np.array(pybullet.getMatrixFromQuaternion(q)).reshape(3, 3)
        assert np.allclose(m, r, atol=1e-12)


def test_frame_transforms_is_the_chain_of_link_transforms_to_the_bit() -> None:
    # frame_transforms writes every link's entries at once; dh_link_transform is the reference.
    rng = np.random.default_rng(7)
    tables = [kin.UMAY_DH] + [
        tuple(kin.DHRow(*rng.uniform(-2.0, 2.0, size=4)) for _ in range(6)) for _ in range(20)
    ]
    for dh in tables:
        q = rng.uniform(-3.0, 3.0, size=6)
        t = np.eye(4)
        for row, pose, qi in zip(dh, kin.frame_transforms(q, dh), q, strict=True):
            t = t @ kin.dh_link_transform(row, float(qi))
            assert np.array_equal(pose, t)


def test_pinv_is_numpys_to_the_bit_whatever_the_rank() -> None:
    rng = np.random.default_rng(8)
    for shape, rank in [((6, 6), 6), ((6, 6), 4), ((8, 6), 6), ((1, 6), 1), ((6, 3), 2)]:
        a = rng.normal(size=(shape[0], rank)) @ rng.normal(size=(rank, shape[1]))
        assert np.array_equal(kin.pinv(a), np.linalg.pinv(a))
    for empty in (np.zeros((0, 6)), np.zeros((6, 0))):
        assert np.array_equal(kin.pinv(empty), np.linalg.pinv(empty))
