"""The pybullet world: robot, table, target marker and the torso RGB-D camera. No networking.

Frames: pybullet's world frame is the arm base frame (DH frame 0): x towards the table, y up,
z to the robot's right (see ``common.kinematics``); gravity points along -y.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet
from pybullet_utils.bullet_client import BulletClient

from common import kinematics as kin
from common.camera import CameraIntrinsics, project
from common.config import Scenario
from services.sim.sensor_model import exposed_rgb, noisy_depth
from services.sim.urdf import robot_urdf

FloatArray = np.ndarray

TABLE_TOP_Y_M = -0.40  # table top height in the base frame (y up)
TABLE_COLOUR = (0.86, 0.84, 0.80, 1.0)
FLOOR_COLOUR = (0.55, 0.57, 0.60, 1.0)
RED = (0.85, 0.08, 0.08, 1.0)
OBJECT_COLOUR = (0.45, 0.55, 0.70, 1.0)  # a blue-grey toy block under the red marker
MOTOR_FORCE_N_M = 200.0


def opengl_view_matrix(t_base_cam: FloatArray) -> list[float]:
    """pybullet view matrix (column-major) for an optical-frame camera pose.

    OpenGL's camera looks down its -z with y up; the optical frame looks down +z with y down.
    """
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    view = flip @ np.linalg.inv(t_base_cam)
    return view.flatten(order="F").tolist()


def opengl_projection_matrix(k: CameraIntrinsics, near_m: float, far_m: float) -> list[float]:
    """Column-major OpenGL projection whose pixel centres match ``u = fx·x + cx`` exactly.

    The off-centre terms place the principal point so that rendered pixels line up with the
    pinhole model of :mod:`common.camera` (pixel centres at integer coordinates).
    """
    w, h = k.width_px, k.height_px
    p = np.zeros((4, 4))
    p[0, 0] = 2.0 * k.fx_px / w
    p[1, 1] = 2.0 * k.fy_px / h
    # TinyRenderer samples pixel (row i, column j) at (u, v) = (j - 0.5, i + 0.5) of the
    # frustum it is given (measured against projected truth), hence the half-pixel terms.
    p[0, 2] = -(2.0 * k.cx_px / w - 1.0)  # image x right; OpenGL looks down -z
    p[1, 2] = 2.0 * (k.cy_px + 1.0) / h - 1.0  # image y down vs OpenGL y up
    p[2, 2] = -(far_m + near_m) / (far_m - near_m)
    p[2, 3] = -2.0 * far_m * near_m / (far_m - near_m)
    p[3, 2] = -1.0
    return p.flatten(order="F").tolist()


def depth_buffer_to_metres(buffer: FloatArray, near_m: float, far_m: float) -> FloatArray:
    """OpenGL depth buffer (0..1, non-linear) to Z along the optical axis (m), float32.

    Pixels at the far plane (nothing rendered) become 0, the "invalid" value of a Kinect.
    """
    b = np.asarray(buffer, dtype=np.float64)
    z = far_m * near_m / (far_m - (far_m - near_m) * b)
    z[b >= 1.0] = 0.0
    return z.astype(np.float32)


@dataclass(frozen=True)
class Truth:
    hand_marker_pose: FloatArray
    target_marker_pose: FloatArray
    hand_corners_px: FloatArray
    target_corners_px: FloatArray
    ee_position_m: FloatArray


class World:
    """One pybullet simulation of the scenario, in DIRECT mode (no GUI)."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.intrinsics = scenario.camera.intrinsics()
        self.camera_pose = scenario.camera.pose()
        self._view = opengl_view_matrix(self.camera_pose)
        self._proj = opengl_projection_matrix(
            self.intrinsics, scenario.camera.near_m, scenario.camera.far_m
        )
        self.target_pose = kin.target_marker_pose(
            np.array(scenario.target.position), scenario.target.yaw
        )
        self.kinect = scenario.camera.kinect
        self._sensor_rng = np.random.default_rng(self.kinect.seed)
        self.physics_dt_s = 1.0 / scenario.sim.physics_hz
        self.sim_time_s = 0.0
        self.client = BulletClient(connection_mode=pybullet.DIRECT)
        self.client.setGravity(*(-9.81 * kin.BASE_UP))
        self.client.setTimeStep(self.physics_dt_s)
        self.robot = self._load_robot()
        self.joint_ids = self._arm_joint_ids()
        self.ee_link = self._link_index("ee_link")
        self._build_scene()
        self.reset(np.array(scenario.robot.q0))

    # --- construction ---------------------------------------------------------------------
    def _load_robot(self) -> int:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "umay.urdf"
            path.write_text(robot_urdf(self.scenario.marker.size_m))
            return self.client.loadURDF(
                str(path), useFixedBase=True, flags=pybullet.URDF_USE_INERTIA_FROM_FILE
            )

    def _arm_joint_ids(self) -> list[int]:
        by_name = {
            self.client.getJointInfo(self.robot, j)[1].decode(): j
            for j in range(self.client.getNumJoints(self.robot))
        }
        return [by_name[f"joint_{i}"] for i in range(1, kin.N_JOINTS + 1)]

    def _link_index(self, name: str) -> int:
        for j in range(self.client.getNumJoints(self.robot)):
            if self.client.getJointInfo(self.robot, j)[12].decode() == name:
                return j
        raise KeyError(name)

    def _box(
        self,
        half_extents: tuple[float, float, float],
        position: FloatArray,
        rgba: tuple[float, ...],
        collide: bool,
        orientation: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0),
    ) -> int:
        c = self.client
        visual = c.createVisualShape(pybullet.GEOM_BOX, halfExtents=half_extents, rgbaColor=rgba)
        collision = (
            c.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half_extents) if collide else -1
        )
        return c.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=collision,
            baseVisualShapeIndex=visual,
            basePosition=list(position),
            baseOrientation=list(orientation),
        )

    def _build_scene(self) -> None:
        self._box((1.5, 0.01, 1.5), np.array([0.3, -0.76, 0.0]), FLOOR_COLOUR, True)
        top = np.array([0.42, TABLE_TOP_Y_M - 0.02, 0.0])
        self._box((0.28, 0.02, 0.45), top, TABLE_COLOUR, True)
        # The object: a box from the table top up to the red marker, which lies on its top face.
        size = self.scenario.marker.size_m
        top_y = self.target_pose[1, 3] - kin.MARKER_THICKNESS_M
        height = top_y - TABLE_TOP_Y_M
        if height > 0.005:
            side = size * 1.25
            centre_obj = np.array(
                [self.target_pose[0, 3], TABLE_TOP_Y_M + height / 2, self.target_pose[2, 3]]
            )
            quat_obj = self.client.getQuaternionFromEuler([0.0, self.scenario.target.yaw, 0.0])
            self._box((side / 2, height / 2, side / 2), centre_obj, OBJECT_COLOUR, True, quat_obj)
        # The red square itself: visual only.
        centre = self.target_pose[:3, 3] - self.target_pose[:3, 2] * kin.MARKER_THICKNESS_M / 2
        quat = self.client.getQuaternionFromEuler([0.0, self.scenario.target.yaw, 0.0])
        self.target_body = self._box(
            (size / 2, kin.MARKER_THICKNESS_M / 2, size / 2), centre, RED, False, quat
        )

    # --- state ----------------------------------------------------------------------------
    def reset(self, q_rad: FloatArray) -> None:
        for jid, q in zip(self.joint_ids, q_rad, strict=True):
            self.client.resetJointState(self.robot, jid, float(q), 0.0)
        self.set_joint_velocities(np.zeros(kin.N_JOINTS))

    def set_joint_velocities(self, qdot_rad_s: FloatArray) -> None:
        self.client.setJointMotorControlArray(
            self.robot,
            self.joint_ids,
            pybullet.VELOCITY_CONTROL,
            targetVelocities=[float(v) for v in qdot_rad_s],
            forces=[MOTOR_FORCE_N_M] * kin.N_JOINTS,
        )

    def step(self, n_steps: int = 1) -> None:
        for _ in range(n_steps):
            self.client.stepSimulation()
        self.sim_time_s += n_steps * self.physics_dt_s

    def joint_state(self) -> tuple[FloatArray, FloatArray]:
        states = self.client.getJointStates(self.robot, self.joint_ids)
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])

    def ee_pose(self) -> FloatArray:
        """Pose of ``ee_link`` (DH frame 6) in the base frame, from pybullet."""
        state = self.client.getLinkState(self.robot, self.ee_link, computeForwardKinematics=True)
        rot = np.array(self.client.getMatrixFromQuaternion(state[5])).reshape(3, 3)
        return kin.homogeneous(rot, np.array(state[4]))

    # --- sensing --------------------------------------------------------------------------
    def render(self) -> tuple[np.ndarray, np.ndarray]:
        """RGB uint8 (H, W, 3) and depth float32 metres (H, W) from the torso camera, through
        the Kinect sensor model when ``camera.kinect.enabled``."""
        k = self.intrinsics
        _, _, rgba, depth, _ = self.client.getCameraImage(
            k.width_px,
            k.height_px,
            viewMatrix=self._view,
            projectionMatrix=self._proj,
            renderer=pybullet.ER_TINY_RENDERER,
            shadow=0,
            lightDirection=[0.4, -0.3, 1.0],
            flags=pybullet.ER_NO_SEGMENTATION_MASK,
        )
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(k.height_px, k.width_px, 4)[:, :, :3]
        depth_m = depth_buffer_to_metres(
            np.asarray(depth).reshape(k.height_px, k.width_px),
            self.scenario.camera.near_m,
            self.scenario.camera.far_m,
        )
        if self.kinect.enabled:
            rgb = exposed_rgb(rgb, self.kinect, self._sensor_rng)
            depth_m = noisy_depth(depth_m, self.kinect, self._sensor_rng)
        return np.ascontiguousarray(rgb), depth_m

    def truth(self) -> Truth:
        ee = self.ee_pose()
        hand = ee @ kin.hand_marker_in_ee()
        size = self.scenario.marker.size_m
        cam_inv = np.linalg.inv(self.camera_pose)

        def corners_px(pose: FloatArray) -> FloatArray:
            c = kin.marker_corners(pose, size)
            c_cam = (cam_inv @ np.column_stack([c, np.ones(4)]).T).T[:, :3]
            return project(c_cam, self.intrinsics)

        return Truth(
            hand_marker_pose=hand,
            target_marker_pose=self.target_pose,
            hand_corners_px=corners_px(hand),
            target_corners_px=corners_px(self.target_pose),
            ee_position_m=ee[:3, 3],
        )

    def close(self) -> None:
        self.client.disconnect()
