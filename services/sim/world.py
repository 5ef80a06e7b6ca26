"""The pybullet world: robot, table, target marker and the torso RGB-D camera. No networking.

Frames: pybullet's world frame is the arm base frame (DH frame 0): x towards the table, y up,
z to the robot's right (see ``common.kinematics``); gravity points along -y.
"""

from __future__ import annotations

import logging
import os
import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common import kinematics as kin
from common.camera import CameraIntrinsics
from common.config import Scenario
from services.sim.bullet import BulletClient, pybullet
from services.sim.events import SceneState, scene_state
from services.sim.projection import (
    LIGHT_DIRECTION,
    depth_buffer_to_metres,
    opengl_projection_matrix,
    opengl_view_matrix,
)
from services.sim.renderers import close_renderer, open_renderer
from services.sim.scenery import HalfSpace, view_frustum, visible_box
from services.sim.sensor_model import exposed_rgb, noisy_depth
from services.sim.shapes import VisualShape, body_ids, shape_poses, visual_shapes
from services.sim.truth import MarkerView, Truth, square_pixels, truth_corners_px
from services.sim.urdf import (
    CUE_RGBA,
    MIN_BLOCK_HEIGHT_M,
    TABLE_CENTRE_M,
    TABLE_SIZE_M,
    TORSO_CENTRE_M,
    TORSO_COLOUR,
    TORSO_SIZE_M,
    cue_box,
    object_block,
    robot_urdf,
)

FloatArray = np.ndarray
log = logging.getLogger(__name__)

FLOOR_TOP_Y_M = -0.75
TABLE_COLOUR = (0.86, 0.84, 0.80, 1.0)
FLOOR_COLOUR = (0.55, 0.57, 0.60, 1.0)
RED = (0.85, 0.08, 0.08, 1.0)
OBJECT_COLOUR = (0.45, 0.55, 0.70, 1.0)  # a blue-grey toy block under the red marker
OCCLUDER_COLOUR = (0.92, 0.92, 0.90, 1.0)  # a sheet of paper
OCCLUDER_GAP_M = 0.08  # the occluding panel hangs this far in front of the hand's marker
OCCLUDER_SCALE = 2.5  # its side, relative to the marker's apparent size at that distance
HIDDEN_POSITION_M = (0.0, -50.0, 0.0)  # where a hidden body is parked (far below the floor)
MOTOR_FORCE_N_M = 200.0


class DirectClient(BulletClient):
    """A headless (DIRECT) pybullet client. ``BulletClient(pybullet.DIRECT)`` connects with
    ``options=""``, for which pybullet prints a stray ``argv[0]=`` line on stdout, once per
    world: in a campaign's or a pre-launch check's output, hundreds of them. Sets what
    BulletClient's own constructor sets, connecting without options."""

    def __init__(self) -> None:
        self._shapes: dict = {}
        self._pid = os.getpid()
        self._client = pybullet.connect(pybullet.DIRECT)


class World:
    """One pybullet simulation of the scenario, in DIRECT mode (no GUI).

    The camera renders through OpenGL (:mod:`services.sim.gl_renderer`) when
    ``sim.renderer = "gl"`` and an EGL context can be made; else, or when ``sim.renderer =
    "tiny"``, through pybullet's TinyRenderer. :attr:`renderer` is the one in use and
    :attr:`renderer_detail` says which driver draws, or why the fallback was taken.

    ``clip_scenery=False`` draws the torso, table and floor as whole boxes instead of the parts
    of them the camera sees (:mod:`services.sim.scenery`, TinyRenderer only): the same images,
    rendered slower; a reference for tests and measurements. ``cache_scenery=False`` has OpenGL
    draw every shape every frame instead of the torso, table and floor once into the background
    each frame starts from (:mod:`services.sim.gl_renderer`): the same images, the reference."""

    def __init__(
        self, scenario: Scenario, clip_scenery: bool = True, cache_scenery: bool = True
    ) -> None:
        self.scenario = scenario
        self.cache_scenery = cache_scenery
        self.renderer, self.renderer_detail, self._gl = open_renderer(scenario.sim.renderer)
        # OpenGL draws whole boxes (pybullet's mesh visuals cannot be read back), nor needs the cut.
        self.clip_scenery = clip_scenery and self.renderer == "tiny"
        self.intrinsics = scenario.camera.intrinsics()
        self.camera_pose = scenario.camera.pose()
        self._view = opengl_view_matrix(self.camera_pose)
        self._cam_from_world = np.linalg.inv(self.camera_pose)
        self._gl_bodies: tuple[int, ...] = ()
        self._gl_shapes: list[VisualShape] = []
        self._projections: dict[CameraIntrinsics, list[float]] = {}
        self.depth_intrinsics = scenario.camera.depth_intrinsics()
        self.initial_target_pose = kin.target_marker_pose(
            np.array(scenario.target.position), scenario.target.yaw
        )
        self.target_pose = self.initial_target_pose.copy()
        self.scene = scene_state([], 0.0)
        self.occluder_body: int | None = None
        self.kinect = scenario.camera.kinect
        self._sensor_rng = np.random.default_rng(self.kinect.seed)
        self._perfect_buffers: dict[tuple[int, int, int], np.ndarray] = {}
        self.physics_dt_s = 1.0 / scenario.sim.physics_hz
        self.sim_time_s = 0.0
        self.client = DirectClient()
        self.client.setGravity(*(-9.81 * kin.BASE_UP))
        self.client.setTimeStep(self.physics_dt_s)
        self.robot = self._load_robot()
        self.joint_ids = self._arm_joint_ids()
        self.ee_link = self._link_index("ee_link")
        self._build_scene()
        self.reset(np.array(scenario.robot.q0))
        self.update_scene()

    # --- construction ---------------------------------------------------------------------
    def _load_robot(self) -> int:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "umay.urdf"
            marker = self.scenario.marker
            path.write_text(robot_urdf(marker.size_m, marker.orientation_cue))
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
        visual: int | None = None,
    ) -> int:
        """A static box; ``visual``: its visual shape (-1: none), else a box of ``rgba``."""
        c = self.client
        if visual is None:
            visual = c.createVisualShape(
                pybullet.GEOM_BOX, halfExtents=half_extents, rgbaColor=rgba
            )
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

    def _scenery_box(
        self,
        half_extents: tuple[float, float, float],
        centre: FloatArray,
        rgba: tuple[float, ...],
        frustum: list[HalfSpace] | None,
        collide: bool = True,
    ) -> int:
        """A box that never moves, drawn as the part of it inside ``frustum`` (None: whole;
        ``clip_scenery``: see :class:`World`)."""
        if frustum is None:
            return self._box(half_extents, centre, rgba, collide)
        mesh = visible_box(half_extents, centre, self.camera_pose[:3, 3], frustum)
        visual = -1  # out of view: nothing to draw
        if mesh is not None:
            visual = self.client.createVisualShape(
                pybullet.GEOM_MESH,
                vertices=mesh.vertices,
                indices=mesh.indices,
                normals=mesh.normals,
                rgbaColor=rgba,
            )
        return self._box(half_extents, centre, rgba, collide, visual=visual)

    def _build_scene(self) -> None:
        """The object and its marker, then the torso, the table and the floor: nearest first.

        TinyRenderer draws bodies in the order they were made and shades every pixel that is
        nearer than what is drawn there already. Drawn last, the floor behind the table and
        the arm fails the depth test before it is shaded, which saves TinyRenderer the shading
        of every pixel they hide, with bit-identical images (docs/performance.md); cutting the
        torso, table and floor to the view (:mod:`services.sim.scenery`) saves more."""
        # The object: a box from the table top up to the red marker, which lies on its top face.
        size = self.scenario.marker.size_m
        centre, height = object_block(self.target_pose)
        self._target_quat = self.client.getQuaternionFromEuler([0.0, self.scenario.target.yaw, 0.0])
        self.object_body: int | None = None
        if height > MIN_BLOCK_HEIGHT_M:
            side = self.scenario.object_side_m
            self.object_body = self._box(
                (side / 2, height / 2, side / 2),
                centre,
                OBJECT_COLOUR,
                True,
                self._target_quat,
            )
        # The red square itself: visual only.
        self.target_body = self._box(
            (size / 2, kin.MARKER_THICKNESS_M / 2, size / 2),
            self._marker_centre(),
            RED,
            False,
            self._target_quat,
        )
        # Its orientation cue (marker.orientation_cue), a body of its own moved with it.
        self.target_cue_body: int | None = None
        if self.scenario.marker.orientation_cue:
            centre, (side, _, height) = cue_box(self.target_pose, size)
            self.target_cue_body = self._box(
                (side / 2, height / 2, side / 2), centre, CUE_RGBA, False, self._target_quat
            )
        frustum = (
            view_frustum(self.camera_pose, self.intrinsics, self.scenario.camera.near_m)
            if self.clip_scenery
            else None
        )
        tx, ty, tz = TORSO_SIZE_M  # visual only, as the robot's own links do not collide
        torso = (tx / 2, ty / 2, tz / 2)
        self.torso_body = self._scenery_box(
            torso, np.array(TORSO_CENTRE_M), TORSO_COLOUR, frustum, collide=False
        )
        half_table = tuple(side / 2 for side in TABLE_SIZE_M)
        self.table_body = self._scenery_box(
            half_table, np.array(TABLE_CENTRE_M), TABLE_COLOUR, frustum
        )
        floor = np.array([0.3, FLOOR_TOP_Y_M - 0.01, 0.0])
        self.floor_body = self._scenery_box((1.5, 0.01, 1.5), floor, FLOOR_COLOUR, frustum)

    def _marker_centre(self) -> FloatArray:
        return self.target_pose[:3, 3] - self.target_pose[:3, 2] * kin.MARKER_THICKNESS_M / 2

    def _object_centre(self) -> FloatArray:
        """Centre of the block under the marker: straight below the marker, down to the table."""
        return object_block(self.target_pose)[0]

    # --- scenario events ------------------------------------------------------------------
    def update_scene(self) -> SceneState:
        """Put the scene in the state the scenario's events give at the current sim time."""
        state = scene_state(self.scenario.events, self.sim_time_s)
        previous, self.scene = self.scene, state
        moved = not np.array_equal(state.target_offset_m, previous.target_offset_m)
        if moved:
            self.target_pose = self.initial_target_pose.copy()
            self.target_pose[:3, 3] += state.target_offset_m
            if self.object_body is not None:
                self.client.resetBasePositionAndOrientation(
                    self.object_body, self._object_centre().tolist(), self._target_quat
                )
        if moved or state.target_hidden != previous.target_hidden:
            where = HIDDEN_POSITION_M if state.target_hidden else self._marker_centre().tolist()
            self.client.resetBasePositionAndOrientation(
                self.target_body, list(where), self._target_quat
            )
            if self.target_cue_body is not None:
                cue = cue_box(self.target_pose, self.scenario.marker.size_m)[0].tolist()
                self.client.resetBasePositionAndOrientation(
                    self.target_cue_body,
                    list(HIDDEN_POSITION_M) if state.target_hidden else cue,
                    self._target_quat,
                )
        if state.hand_occluded_since_s != previous.hand_occluded_since_s:
            self._place_occluder(state.hand_occluded_since_s is not None)
        return state

    def _place_occluder(self, active: bool) -> None:
        """A paper panel between the camera and the hand's marker, where the marker is when the
        panel is placed (it does not follow the hand: the controller carries a hidden hand
        along the encoders for a moment, the panel stays where it was put)."""
        if self.occluder_body is not None:
            self.client.removeBody(self.occluder_body)
            self.occluder_body = None
        # pybullet gives a new body the id just freed, so the set of ids does not show the
        # change: OpenGL re-reads the meshes (another panel's size) at its next draw.
        self._gl_bodies = ()
        if not active:
            return
        eye = self.camera_pose[:3, 3]
        marker = (self.ee_pose() @ kin.hand_marker_in_ee())[:3, 3]
        distance = float(np.linalg.norm(marker - eye))
        along = (marker - eye) / distance
        side = OCCLUDER_SCALE * self.scenario.marker.size_m * (distance - OCCLUDER_GAP_M) / distance
        x = np.cross(kin.BASE_UP, along)
        x /= np.linalg.norm(x)
        rot = np.column_stack([x, np.cross(along, x), along])  # thin z along the line of sight
        visual = self.client.createVisualShape(
            pybullet.GEOM_BOX, halfExtents=[side / 2, side / 2, 0.001], rgbaColor=OCCLUDER_COLOUR
        )
        self.occluder_body = self.client.createMultiBody(
            baseMass=0.0,
            baseVisualShapeIndex=visual,
            basePosition=(marker - OCCLUDER_GAP_M * along).tolist(),
            baseOrientation=kin.quaternion_xyzw(rot),
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
    def _projection(self, k: CameraIntrinsics) -> list[float]:
        if k not in self._projections:
            cam = self.scenario.camera
            self._projections[k] = opengl_projection_matrix(k, cam.near_m, cam.far_m)
        return self._projections[k]

    def render_perfect(
        self, k: CameraIntrinsics, out: tuple[np.ndarray | None, np.ndarray | None] = (None, None)
    ) -> tuple[np.ndarray, np.ndarray]:
        """Perfect RGB uint8 (H, W, 3) and depth float32 metres (H, W) from the camera's pose,
        with intrinsics ``k`` (the same field of view at another resolution, say). OpenGL
        draws into ``out``'s arrays where given (see :meth:`render`); TinyRenderer ignores
        them."""
        if self._gl is not None:
            return self._gl.read_colour_depth(self._draw_gl(k), out)
        _, _, rgba, depth, _ = self._tiny_image(k, pybullet.ER_NO_SEGMENTATION_MASK)
        # One contiguous copy without alpha: 25× faster than slicing + ascontiguousarray.
        rgb = cv2.cvtColor(
            np.asarray(rgba, dtype=np.uint8).reshape(k.height_px, k.width_px, 4),
            cv2.COLOR_RGBA2RGB,
        )
        depth_m = depth_buffer_to_metres(
            np.asarray(depth).reshape(k.height_px, k.width_px),
            self.scenario.camera.near_m,
            self.scenario.camera.far_m,
        )
        return rgb, depth_m

    @property
    def draws_into_out(self) -> bool:
        """Whether :meth:`render` gives back ``out``'s arrays, drawn in (OpenGL draws into
        them, the sensor model writes into them; TinyRenderer alone draws into arrays of its
        own): messages may then be made on them before the render."""
        return self._gl is not None or self.kinect.enabled

    def render(
        self,
        with_depth: bool = True,
        out: tuple[np.ndarray | None, np.ndarray | None] = (None, None),
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """RGB uint8 (H, W, 3) at the colour resolution and, if ``with_depth``, depth float32
        metres at the depth resolution (registered: same viewpoint and field of view), through
        the Kinect sensor model when ``camera.kinect.enabled``. One render serves both when
        the resolutions agree. ``out``: arrays (colour, depth) the images may be drawn into
        (the slots of a frame ring): the images returned are these arrays where they were,
        fresh ones otherwise."""
        same = self.depth_intrinsics == self.intrinsics
        model = self.kinect if self.kinect.enabled else None
        # With the sensor model on, the perfect images go to buffers of the world's own and the
        # model writes what the camera reports into ``out``'s arrays (no copy into a ring slot).
        k, k_depth = self.intrinsics, self.depth_intrinsics
        if model is None:
            draw = (out[0], out[1] if same else None)
        else:
            draw = (self._perfect_buffer(k, 3), self._perfect_buffer(k, 1))
        rgb, depth_m = self.render_perfect(k, draw)
        if not with_depth:
            depth_m = None
        elif not same:
            draw_depth = out[1] if model is None else self._perfect_buffer(k_depth, 1)
            _, depth_m = self.render_perfect(k_depth, (None, draw_depth))
        if model is not None:
            rgb = exposed_rgb(rgb, model, self._sensor_rng, out=out[0])
            if depth_m is not None:
                depth_m = noisy_depth(depth_m, model, self._sensor_rng, out=out[1])
        return np.ascontiguousarray(rgb), depth_m

    def _perfect_buffer(self, k: CameraIntrinsics, channels: int) -> np.ndarray:
        """A buffer of the world's own, kept between frames, for a perfect image of ``k``'s
        size: colour (uint8, 3 channels) or depth (float32, 1) before the sensor model."""
        key = (k.width_px, k.height_px, channels)
        if key not in self._perfect_buffers:
            shape = (k.height_px, k.width_px, 3) if channels == 3 else (k.height_px, k.width_px)
            self._perfect_buffers[key] = np.empty(shape, np.uint8 if channels == 3 else np.float32)
        return self._perfect_buffers[key]

    def truth(self) -> Truth:
        ee = self.ee_pose()
        hand = ee @ kin.hand_marker_in_ee()
        size = self.scenario.marker.size_m
        cam_inv = np.linalg.inv(self.camera_pose)

        def corners_px(pose: FloatArray) -> FloatArray:
            c = kin.marker_corners(pose, size)
            c_cam = (cam_inv @ np.column_stack([c, np.ones(4)]).T).T[:, :3]
            return truth_corners_px(c_cam, self.intrinsics)

        contact_n, contact_with = self.arm_contacts()
        return Truth(
            hand_marker_pose=hand,
            target_marker_pose=self.target_pose,
            hand_corners_px=corners_px(hand),
            target_corners_px=corners_px(self.target_pose),
            ee_position_m=ee[:3, 3],
            contact_n=contact_n,
            contact_with=contact_with,
        )

    def _scenery_names(self) -> dict[int, str]:
        """The bodies the arm may press on or reach into, by id: the object (when the target
        stands on one), the table and the floor."""
        names = {self.table_body: "table", self.floor_body: "floor"}
        return names if self.object_body is None else {self.object_body: "object", **names}

    def arm_contacts(self) -> tuple[float, tuple[str, ...]]:
        """Ground truth for evaluation: the summed normal force (N) of the arm's contacts
        after the last physics step, and the bodies it touches (sorted names)."""
        names = self._scenery_names()
        force, touched = 0.0, set()
        for c in self.client.getContactPoints(bodyA=self.robot):
            force += float(c[9])
            touched.add(names.get(c[2], "scenery"))
        return force, tuple(sorted(touched))

    def arm_penetration(self) -> tuple[float, str]:
        """How deep (m) the arm reaches into the object, the table or the floor in its posture
        now, and into which (0.0 and "" when it is clear of them). A start posture inside the
        scenery cannot be simulated: the solver pushes the bodies apart at the first step."""
        deepest, into = 0.0, ""
        for body, name in self._scenery_names().items():
            for p in self.client.getClosestPoints(bodyA=self.robot, bodyB=body, distance=0.0):
                if -p[8] > deepest:
                    deepest, into = -float(p[8]), name
        return deepest, into

    def marker_visibility(self, touch_px: float = 6.0) -> dict[str, MarkerView]:
        """Ground truth for evaluation: how much of each marker the camera sees, from a
        segmentation render. Keys ``hand`` and ``target``; see :class:`MarkerView`."""
        seg = self.segmentation(self.intrinsics)
        truth = self.truth()
        own = {"hand": [self.robot + ((self.ee_link + 1) << 24)], "target": [self.target_body]}
        if self.target_cue_body is not None:  # the hand's cue is drawn by its own link
            own["target"].append(self.target_cue_body)
        corners = {"hand": truth.hand_corners_px, "target": truth.target_corners_px}
        robot = (seg >= 0) & ((seg & ((1 << 24) - 1)) == self.robot)
        out = {}
        for name, quad in corners.items():
            inside, total = square_pixels(quad, -1.5, seg.shape)  # its edge pixels aside
            seen = np.count_nonzero(np.isin(seg[inside], own[name]))
            around, around_total = square_pixels(quad, touch_px, seg.shape)
            touched = np.count_nonzero(robot[around] & (seg[around] != own[name][0])) > 0
            touched |= np.count_nonzero(around) < around_total  # at the image border
            out[name] = MarkerView(seen / total if total else 0.0, bool(touched))
        return out

    def segmentation(self, k: CameraIntrinsics) -> np.ndarray:
        """Id image (int32, H×W) of what each pixel sees: pybullet's segmentation value
        ``body + ((link + 1) << 24)``, -1 for nothing; from either renderer."""
        if self._gl is not None:
            return self._gl.read_ids(self._draw_gl(k, ids=True))
        seg = self._tiny_image(k, pybullet.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX)[4]
        return np.asarray(seg, dtype=np.int32).reshape(k.height_px, k.width_px)

    def _tiny_image(self, k: CameraIntrinsics, flags: int) -> tuple:
        """pybullet's getCameraImage through TinyRenderer from the camera's pose."""
        return self.client.getCameraImage(
            k.width_px,
            k.height_px,
            viewMatrix=self._view,
            projectionMatrix=self._projection(k),
            renderer=pybullet.ER_TINY_RENDERER,
            shadow=0,
            lightDirection=list(LIGHT_DIRECTION),
            flags=flags,
        )

    def _draw_gl(self, k: CameraIntrinsics, ids: bool = False) -> Any:
        """Draw the scene as it is now through OpenGL, colour and depth or with ``ids`` the id
        image (meshes re-read when bodies changed)."""
        assert self._gl is not None
        bodies = body_ids(self.client)
        if bodies != self._gl_bodies:
            self._gl_shapes = visual_shapes(self.client)
            # The scenery never moves: OpenGL draws it once, into the background it starts from.
            scenery = frozenset((self.torso_body, self.table_body, self.floor_body))
            self._gl.set_shapes(self._gl_shapes, scenery if self.cache_scenery else frozenset())
            self._gl_bodies = bodies
        cam = self.scenario.camera
        return self._gl.draw(
            shape_poses(self.client, self._gl_shapes),
            self._cam_from_world,
            k,
            cam.near_m,
            cam.far_m,
            np.array(LIGHT_DIRECTION),
            ids=ids,
        )

    def close(self) -> None:
        if self._gl is not None:
            close_renderer(self._gl)
            self._gl = None
        self.client.disconnect()
