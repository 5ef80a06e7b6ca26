"""Eye-to-hand IBVS: the control law and its state, as ViSP's ``vpServo`` holds it.

Each frame :class:`IbvsController` takes both markers as vision measured them and gives the
hand's twist ``(v, ω) = λ · M · e`` in the base frame, or a hold that says why. The pieces are
in modules of their own: the interaction matrices and each strategy's ``M``
(:mod:`.interaction`, with the sign convention), the goal in the image (:mod:`.goal`), which
target corner each hand corner goes to (:mod:`.pairing`), when the error counts as converged
(:mod:`.convergence`), target acquisition (:mod:`.acquisition`), the clearance above the
object (:mod:`.clearance`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from common import kinematics as kin
from common.camera import CameraIntrinsics, pixel_to_normalized, project
from common.config import ControllerConfig, JacobianMode, Scenario
from common.kinematics import BASE_UP
from common.marker import Marker
from services.controller import acquisition as acq
from services.controller.arm import ArmReading
from services.controller.convergence import ConvergenceWindow
from services.controller.goal import (
    GOAL_BEHIND_CAMERA,
    TargetMemory,
    desired_observation,
    in_front_of_camera,
    may_be_behind_the_hand,
)
from services.controller.hand import HandMemory
from services.controller.interaction import (
    USES_CURRENT,
    USES_DESIRED,
    constant_interaction_matrix,
    control_matrix,
    image_feature_rate,
    interaction_matrix,
    points3d_control_matrix,
)
from services.controller.pairing import (
    choose_pairing,
    label_shift,
    pairing_costs_px2,
    relabelled_pairing,
    rolled,
)
from services.controller.reach import carried_over, goal_poses_ee, goal_posture, goal_postures
from services.controller.stability import frozen_matrix_stability
from services.controller.twist import camera_twist_to_base_ee, clamp_twist

FloatArray = NDArray[np.float64]

# The goal's move (m) after which the pairings' goal postures are checked again: a target moved
# by a few centimetres, or more, can put another pairing's posture in or out of reach.
REACH_RECHECK_M = 0.02
# The goal's move (m) after which the current pairing's goal posture alone is solved again,
# from its last one (a few iterations): the forearm's funnel (.forearm.margin_near_goal) is
# centred on it, and on a moving target a posture 2 cm old would leave the funnel behind.
POSTURE_RESOLVE_M = 0.002


@dataclass(frozen=True)
class ControlOutput:
    twist_base_ee: FloatArray  # (v, ω) in the base frame at the end-effector origin
    valid: bool
    error_px_rms: float
    converged: bool
    target_remembered: bool = False  # s* from memory: the hand hides the target
    # Why the twist is zero, when not valid; while acquiring (valid), what the motion is for
    # (``acquiring: ...``): the wire format's ``hold_reason`` carries both.
    hold_reason: str = ""
    phase: str = "servoing"  # servoing / acquiring / holding
    hold_since_s: float | None = None  # sim time the current hold began
    lifted: bool = False  # the twist was corrected to keep the hand above the object (clearance)
    # The law's M of (v, ω) = λ · M · e (6×2N or 6×3N, camera frame at the camera origin):
    # W = M⁺ is the law's own model of the features' rate per twist, by which a correction of
    # the twist changes the image (services.controller.constrained; computed only when a
    # correction is needed). None when the twist is not the law's.
    control_matrix: FloatArray | None = None
    hand_predicted: bool = False  # servoed on the hand carried by the encoders (.hand)
    # s* of the law (4×2 px), paired: row i is where hand corner i is driven. None: no law.
    goal_px: FloatArray | None = None

    @property
    def status(self) -> str:
        """``servoing``, ``acquiring: why, attempt i/n`` or ``holding: why``."""
        if self.phase == "holding":
            return f"holding: {self.hold_reason}"
        return self.hold_reason if self.phase == "acquiring" else self.phase


ACQUIRING = "acquiring"
ACQUISITION_FAILED = "acquisition failed"


def is_stuck(hold_since_s: float | None, now_s: float, stuck_after_s: float) -> bool:
    """A hold that began at ``hold_since_s`` has lasted ``stuck_after_s`` by ``now_s``."""
    return hold_since_s is not None and now_s - hold_since_s >= stuck_after_s


def describe_hold(
    reason: str, hold_since_s: float | None, now_s: float, config: ControllerConfig
) -> str:
    """What a hold waits for and for how long, for ``umay status``:
    ``holding: target partial (stuck, for 6.0 s, since sim time 0.00 s)``."""
    since = now_s if hold_since_s is None else hold_since_s
    stuck = "stuck, " if is_stuck(hold_since_s, now_s, config.stuck_after_s) else ""
    return f"holding: {reason} ({stuck}for {now_s - since:.1f} s, since sim time {since:.2f} s)"


@dataclass
class IbvsController:
    """Per-frame IBVS step.

    State: the frozen constant Jacobian, the errors convergence is judged on, the last usable
    views of both markers (the target's with its recent motion, :class:`.goal.TargetMemory`;
    the hand's, :class:`.hand.HandMemory`), the corner pairing and target acquisition. While
    either marker is not usable (and cannot be remembered), the controller holds (zero twist,
    ``valid`` False, ``hold_reason`` says why) and resumes when it is back.
    """

    config: ControllerConfig
    t_base_cam: FloatArray  # assumed camera pose (calibration), never the simulator's truth
    approach_height_m: float = 0.0
    # Corners labelled physically by the markers' orientation cue (marker.orientation_cue):
    # hand corner i goes to target corner i however far the hand is turned, so a start turned
    # by 180° about the optical axis is servoed as such, not as the least turn.
    oriented_markers: bool = False
    # The side of the object's top face (m; the scenario's object model, target.object_side_m),
    # for keeping the forearm off it (step.above_the_target); None: not kept off it.
    object_side_m: float | None = None
    l_constant: FloatArray | None = None  # 8×6, rows in the target's own corner labelling
    # The frozen matrix's local stability at the goal it was built at (.stability; constant
    # only, None before): at or below 0 the law drives the hand away from its own goal.
    goal_stability: float | None = None
    # s − s* (px, 2N) of the last frames servoed on a still, seen goal, and their plateau
    window: ConvergenceWindow = field(default_factory=ConvergenceWindow)
    pairing: int | None = None  # hand corner i goes to target corner (i + pairing) % 4
    # Which pairings' goal postures the arm reaches (.reach; None before, or without the joint
    # angles): the least turn is chosen among those. Checked from where the arm first servoes,
    # again once the goal has moved (its centroid, camera frame, when last checked).
    reachable: list[bool] | None = None
    reachable_for_m: FloatArray | None = None
    # Each pairing's goal posture as the same check solved it (4×6, rad; None with it): near
    # the goal the forearm's margin falls to its clearance there (forearm.margin_near_goal).
    reach_postures: FloatArray | None = None
    posture_for_m: FloatArray | None = None  # the goal's centroid (camera frame) it was for
    # The pairings' goal orientations when they were checked, and whether vision has lost the
    # hand since (or it was carried by the encoders): on its return its corners may be
    # labelled afresh, which shifts the pairings' indices (.reach.carried_over).
    reach_rotations: FloatArray | None = None
    reach_stale: bool = False
    # Each marker's corners as last used (seen, fitted or carried): vision labels a marker
    # afresh when it has lost it or restarted, which the next view shows (._follow_labels).
    hand_px: FloatArray | None = None
    target_px: FloatArray | None = None
    # The target's last usable view and motion, and whether the goal is a prediction.
    target_memory: TargetMemory = field(default_factory=TargetMemory)
    hold_since_s: float | None = None  # sim time the current hold began
    acquisition: acq.Acquisition | None = None
    acquisitions: int = 0  # attempts made since the last convergence
    acquisition_failed: str = ""  # what acquisition could not uncover (then it holds)
    # The hand's last usable view, to carry along the encoders while vision cannot use it.
    hand_memory: HandMemory = field(default_factory=HandMemory)
    _zero: FloatArray = field(default_factory=lambda: np.zeros(6))
    # The constant strategy's M (read-only) with the frozen matrix and the pairing it is for:
    # M is made again only when either has changed (the matrix is replaced, never written).
    _constant_m: tuple[FloatArray, int, FloatArray] | None = field(default=None, repr=False)
    # The last goal made (.goal.desired_observation) and what it was made from: a still target
    # is measured the same to the bit frame after frame (or remembered), its goal with it.
    _goal_memo: tuple[tuple[bytes, bytes, float, CameraIntrinsics], Marker] | None = field(
        default=None, repr=False
    )

    @classmethod
    def of(cls, scenario: Scenario) -> IbvsController:
        """The controller a scenario describes, with the camera pose it assumes (the
        calibration, never the simulator's truth)."""
        return cls(
            scenario.controller,
            scenario.camera.assumed_pose(),
            scenario.target.approach_height_m,
            oriented_markers=scenario.marker.orientation_cue,
            object_side_m=scenario.object_side_m,
        )

    def step(
        self,
        hand: Marker,
        target: Marker,
        k: CameraIntrinsics,
        arm: ArmReading,
        t_s: float = 0.0,
    ) -> ControlOutput:
        """One control step on the markers seen in the camera frame taken at sim time ``t_s``
        with the arm as the encoders read it in the same frame (:class:`.arm.ArmReading`)."""
        hand_predicted = False
        if arm.t_base_ee is not None:
            hand, hand_predicted = self.hand_memory.now(
                hand, arm.t_base_ee, self.t_base_cam, k, t_s, self.config.predict_hand_s
            )
        seen = target
        target, remembered, seen_again = self.target_memory.now(target, hand, k, t_s)
        if seen_again:  # the window's errors were against the prediction: afresh
            self.window.clear()
        self._follow_labels(hand, target)
        if self.acquisition is not None:
            if seen.usable or not hand.usable or not self.config.acquire:
                self.acquisition = None  # uncovered (or the hand lost): back to the rules
            else:
                return self._acquire(hand, k, arm.p_ee_base_m, t_s)
        # The hand is servoed on when seen whole, or fitted from its edges (its own forearm
        # bordering its marker in the image): vision publishes a fit only when it runs along
        # the marker's true edges to a fraction of a pixel, pins the pose down and shows most
        # of the marker, so a fitted hand's corners are as good as a whole one's.
        if not hand.usable or hand_predicted:
            self.reach_stale = self.reachable is not None
        if not (hand.usable and target.usable):
            return self._hold(hand, target, seen, k, arm, t_s)
        # The target first: raised towards the camera from behind it, its goal could be in front.
        if not in_front_of_camera(target):
            return self._hold_for(GOAL_BEHIND_CAMERA, t_s)
        with np.errstate(divide="ignore", invalid="ignore"):  # a goal at 0 depth: held next
            goal = self._goal(target, k)
        if not in_front_of_camera(goal):
            return self._hold_for(GOAL_BEHIND_CAMERA, t_s)
        self.hold_since_s = None
        q, t_base_ee = arm.q_rad, arm.t_base_ee
        if q is not None and t_base_ee is not None and self._pairing_open() and not hand_predicted:
            self._check_reach(hand, goal, q, t_base_ee)
            self._follow_goal_posture(hand, goal, t_base_ee)
        return self._servo(hand, goal, k, arm, t_s, remembered, hand_predicted)

    def _goal(self, target: Marker, k: CameraIntrinsics) -> Marker:
        """:func:`.goal.desired_observation` of ``target``: the last one made when made from the
        same points, depth uncertainties, approach height and intrinsics."""
        if self.approach_height_m == 0.0:
            return target  # the goal is the target itself, pixels and all
        key = (
            np.asarray(target.points_m, dtype=float).tobytes(),
            np.asarray(target.depth_sigma_m, dtype=float).tobytes(),
            self.approach_height_m,
            k,
        )
        memo = self._goal_memo
        if memo is not None and memo[0] == key:
            return memo[1]
        goal = desired_observation(target, self.approach_height_m, k)
        self._goal_memo = (key, goal)
        return goal

    def _follow_labels(self, hand: Marker, target: Marker) -> None:
        """Keep what is indexed by corner or by pairing on the same physical corners when
        vision has labelled a marker afresh since the last frame (after it lost the marker, or
        a restart of vision, whose tracker starts with no labels to keep): the pairing's index,
        the constant matrix's rows (the target's labels), the acquisition's goal (the hand's),
        and the reach verdicts with their postures and goal orientations.
        Else a fresh vision's labels, a quarter turn from the old ones, would have the hand
        servoed to a pairing it was never meant to take, or held off the one it must."""
        hand_shift = target_shift = 0
        if hand.usable:
            if self.hand_px is not None:
                hand_shift = label_shift(self.hand_px, hand.corners_px)
            self.hand_px = hand.corners_px
        if target.usable:
            if self.target_px is not None:
                target_shift = label_shift(self.target_px, target.corners_px)
            self.target_px = target.corners_px
        if hand_shift == 0 and target_shift == 0:
            return
        self.window.clear()  # its errors are by corner
        if self.pairing is not None:
            self.pairing = relabelled_pairing(self.pairing, hand_shift, target_shift)
        if self.l_constant is not None:
            self.l_constant = np.roll(self.l_constant, -2 * target_shift, axis=0)
        if self.acquisition is not None:
            goal_px = np.roll(self.acquisition.goal_px, -hand_shift, axis=0)
            self.acquisition = replace(self.acquisition, goal_px=goal_px)
        # Pairing k is pairing k + shift now: the verdicts, postures and goal orientations move
        # with it at once (not at the next reach check, which waits while the hand is carried).
        shift = hand_shift - target_shift
        if self.reachable is not None:
            self.reachable = [self.reachable[(k - shift) % 4] for k in range(4)]
        for name in ("reach_postures", "reach_rotations"):
            values = getattr(self, name)
            if values is not None:
                setattr(self, name, np.roll(values, shift, axis=0))

    def _check_reach(
        self, hand: Marker, goal: Marker, q_rad: FloatArray, t_base_ee: FloatArray
    ) -> None:
        """Which pairings' goal postures the arm reaches from ``q_rad``: on the first frame
        servoed and again once the goal has moved by :data:`REACH_RECHECK_M`; once vision sees
        the hand after it lost it, the verdicts are carried over to the pairings' indices
        as its corners are labelled now (:attr:`reach_stale`)."""
        centroid = kin.centroid(goal.points_m)
        last = self.reachable_for_m
        moved = last is None or kin.norm(centroid - last) >= REACH_RECHECK_M
        if not (moved or self.reach_stale):
            return
        poses = goal_poses_ee(hand, goal, self.t_base_cam, t_base_ee)
        rotations = poses[:, :3, :3]
        if moved or self.reachable is None or self.reach_rotations is None:
            self.reach_postures, self.reachable = goal_postures(poses, q_rad)
            self.reachable_for_m = self.posture_for_m = centroid
        else:
            then = self.reach_rotations
            self.reachable = carried_over(self.reachable, then, rotations)
            if self.reach_postures is not None:
                self.reach_postures = np.array(carried_over(self.reach_postures, then, rotations))
        self.reach_rotations, self.reach_stale = rotations, False

    def _follow_goal_posture(self, hand: Marker, goal: Marker, t_base_ee: FloatArray) -> None:
        """The current pairing's goal posture solved again from its last one once the goal
        has moved by :data:`POSTURE_RESOLVE_M` since (the verdicts stay the check's)."""
        k, postures, last = self.pairing, self.reach_postures, self.posture_for_m
        if k is None or postures is None or last is None:
            return
        centroid = kin.centroid(goal.points_m)
        if kin.norm(centroid - last) < POSTURE_RESOLVE_M:
            return
        pose = goal_poses_ee(hand, goal, self.t_base_cam, t_base_ee, pairings=[k])[0]
        q_goal, reached = goal_posture(pose, postures[k])
        if reached:  # else the last one stands, until the goal has moved as far again
            postures[k] = q_goal
        self.posture_for_m = centroid

    def goal_posture_rad(self) -> FloatArray | None:
        """The joint angles the current pairing's goal asks for, as the reach check solved
        them; None before a check, with the check turned off, or when that posture is beyond
        the joint limits."""
        postures, reached, k = self.reach_postures, self.reachable, self.pairing
        if postures is None or reached is None or k is None or not self._pairing_open():
            return None
        return postures[k] if reached[k] else None

    def _pairing_open(self) -> bool:
        """Whether the corner pairing is a choice to make (a plain square) and the goal
        postures are to be checked for it."""
        return not self.oriented_markers and self.config.reachable_pairing

    def _hold(
        self,
        hand: Marker,
        target: Marker,
        seen: Marker,
        k: CameraIntrinsics,
        arm: ArmReading,
        t_s: float,
    ) -> ControlOutput:
        """A marker cannot be used (``target``: as used, ``seen``: as vision saw it): hold,
        or begin uncovering a target the hand may be in front of."""
        self.window.clear()
        which = "hand" if not hand.usable else "target"
        state = hand.state if not hand.usable else target.state
        if self.hold_since_s is None:
            self.hold_since_s = t_s
        reason = f"{which} {state}"
        # A target never seen at all is in the image (the pre-launch check makes sure):
        # something, most likely the arm, is in front of it.
        behind = may_be_behind_the_hand(seen) or self.target_memory.last is None
        if hand.usable and behind and self.config.acquire:
            if self.acquisition_failed:
                reason = self.acquisition_failed
            elif t_s - self.hold_since_s >= self.config.acquire_after_s:
                started = self._start_acquisition(reason, hand, k, arm, t_s)
                if started is not None:
                    return started
                reason = self.acquisition_failed
        return self._hold_for(reason, t_s)

    def _hold_for(self, reason: str, t_s: float) -> ControlOutput:
        """A zero twist, for ``reason``, the hold's start kept from its first frame."""
        self.window.clear()
        if self.hold_since_s is None:
            self.hold_since_s = t_s
        return ControlOutput(
            self._zero.copy(), False, 0.0, False, False, reason, "holding", self.hold_since_s
        )

    def _servo(
        self,
        hand: Marker,
        target: Marker,
        k: CameraIntrinsics,
        arm: ArmReading,
        t_s: float,
        remembered: bool,
        hand_predicted: bool,
    ) -> ControlOutput:
        """The law's twist on both markers usable, ``target`` the desired features above the
        target (``remembered``: the target from memory; ``hand_predicted``: the hand carried
        by the encoders), and whether it converged."""
        if self.l_constant is None:
            depth = self.config.constant_depth
            self.l_constant = constant_interaction_matrix(target, k, depth)
            if self.config.mode is JacobianMode.CONSTANT:
                self.goal_stability = frozen_matrix_stability(self.l_constant, target, k)
        if self.oriented_markers:
            self.pairing = 0
        else:
            costs = pairing_costs_px2(hand.corners_px, target.corners_px)
            if self._pairing_open() and self.reachable is not None and any(self.reachable):
                costs = np.where(self.reachable, costs, np.inf)
            self.pairing = choose_pairing(costs, self.pairing)
        target = rolled(target, self.pairing)
        track = self.config.track_target_motion
        velocity = self.target_memory.motion.velocity_m_s(t_s) if track else np.zeros(3)
        if self.config.mode is JacobianMode.POINTS3D:
            error, m = self._points3d_law(hand, target)
            target_rate = np.tile(velocity, len(target.points_m))
        else:
            s_star = pixel_to_normalized(target.corners_px, k)  # the law's and the rate's
            error, m = self._image_law(hand, target, s_star, k)
            target_rate = image_feature_rate(s_star, target.depth_m, velocity)
        # ė = ṡ − ṡ* = −λe, with ṡ* the goal's own motion fed forward (zero for a still target).
        twist_cam = m @ (self.config.gain * error - target_rate)
        twist = camera_twist_to_base_ee(twist_cam, self.t_base_cam, arm.p_ee_base_m)
        twist = clamp_twist(twist, self.config.max_linear_m_s, self.config.max_angular_rad_s)
        # s − s* (px, 2N): this frame's error, and its share of convergence's window
        error_px = (np.asarray(hand.corners_px) - np.asarray(target.corners_px)).ravel()
        err_px = float(np.sqrt((error_px**2).mean()))  # feature_error_px_rms
        # On a target believed to move the hand is tracking, not done; nor on a hand carried by
        # the encoders. On a prediction of where a hidden target went it may settle, but it is
        # not done either: the target must be seen there first.
        still = not velocity.any()  # slower than motion.STILL_SPEED_M_S
        if still and not hand_predicted:
            self.window.add(error_px, self.config)
        else:
            self.window.clear()
        settled = self.window.settled(t_s, self.config)
        predicted = self.target_memory.predicted
        converged = settled and not predicted
        if converged:
            self.acquisitions, self.acquisition_failed = 0, ""
        # On a prediction the hand can sit forever: once it has settled there (as it would
        # have converged on a target seen) and the target is believed still, uncover it to see
        # whether it is really there. Judged like convergence, on the averaged error or its
        # plateau: a hand wobbling a few hundredths of a pixel about 0.25 px was never under
        # it for five frames in a row, and sat on the prediction until it was reported stalled.
        if settled and predicted and self.config.acquire:
            self.window.clear()
            why = "predicted target unconfirmed"
            started = self._start_acquisition(why, hand, k, arm, t_s)
            if started is not None:
                return started
        return ControlOutput(
            twist, True, err_px, converged, remembered,
            control_matrix=m, hand_predicted=hand_predicted, goal_px=target.corners_px,
        )  # fmt: skip

    def _start_acquisition(
        self,
        why: str,
        hand: Marker,
        k: CameraIntrinsics,
        arm: ArmReading,
        t_s: float,
    ) -> ControlOutput | None:
        """Begin uncovering the target (None, with ``acquisition_failed`` set, when no
        attempt is left or no image direction is open)."""
        left = self.config.acquire_attempts - self.acquisitions
        started = None
        if left > 0:
            elbow_px = self._image_of(arm.elbow_base_m, k)
            hand_centre_m = hand.points_m.mean(axis=0)
            up_cam = self.t_base_cam[:3, :3].T @ BASE_UP
            up_px = project((hand_centre_m + 0.02 * up_cam)[None, :], k)[0]
            up_px = up_px - hand.corners_px.mean(axis=0)
            started = acq.start(why, t_s, hand.corners_px, elbow_px, k, up_px)
        if started is None:
            self.acquisition_failed = (
                f"{ACQUISITION_FAILED}: {why} after {self.acquisitions} attempt(s)"
            )
            return None
        self.acquisition = started
        self.acquisitions += 1
        self.hold_since_s = None
        self.window.clear()
        return self._acquire(hand, k, arm.p_ee_base_m, t_s)

    def _image_of(self, point_base_m: FloatArray | None, k: CameraIntrinsics) -> FloatArray | None:
        """A point's image through the assumed camera pose (None: unknown or behind)."""
        if point_base_m is None:
            return None
        rot, origin = self.t_base_cam[:3, :3], self.t_base_cam[:3, 3]
        p_cam = rot.T @ (np.asarray(point_base_m, dtype=float) - origin)
        if p_cam[2] <= 1e-3:
            return None
        return project(p_cam[None, :], k)[0]

    def _acquire(
        self, hand: Marker, k: CameraIntrinsics, p_ee_base_m: FloatArray, t_s: float
    ) -> ControlOutput:
        """One step of the acquisition under way: its twist, or a hold once it has failed."""
        assert self.acquisition is not None
        cfg = self.config
        before = self.acquisition
        after = acq.advance(before, hand.corners_px, t_s, cfg.acquire_attempt_s, k)
        if after is not None and after.attempt != before.attempt:
            self.acquisitions += 1
        if after is None or self.acquisitions > cfg.acquire_attempts:
            self.acquisition = None
            self.acquisitions = min(self.acquisitions, cfg.acquire_attempts)
            self.acquisition_failed = (
                f"{ACQUISITION_FAILED}: {before.why} after {self.acquisitions} attempt(s) "
                f"from {before.started_s:.2f} s"
            )
            self.hold_since_s = t_s
            return ControlOutput(
                self._zero.copy(), False, 0.0, False, False, self.acquisition_failed,
                "holding", t_s,
            )  # fmt: skip
        self.acquisition = after
        twist_cam = acq.acquisition_twist_cam(
            hand.corners_px, hand.depth_m, after.goal_px, k, cfg.acquire_gain
        )
        twist = camera_twist_to_base_ee(twist_cam, self.t_base_cam, p_ee_base_m)
        twist = clamp_twist(
            twist, min(cfg.acquire_max_linear_m_s, cfg.max_linear_m_s), cfg.max_angular_rad_s
        )
        reason = after.describe(self.acquisitions, cfg.acquire_attempts)
        return ControlOutput(twist, True, 0.0, False, False, reason, ACQUIRING)

    def _image_law(
        self, hand: Marker, target: Marker, s_star: FloatArray, k: CameraIntrinsics
    ) -> tuple[FloatArray, FloatArray]:
        """``(e, M)`` on the normalized image points (constant, dynamic, pmj, mpj); ``target``
        already paired with the hand's corners, ``s_star`` its normalized points."""
        s = pixel_to_normalized(hand.corners_px, k)
        error = (s - s_star).reshape(-1)
        mode = self.config.mode
        # Only the matrices this strategy uses (the controller's share of the loop's latency).
        l_current = interaction_matrix(s, hand.depth_m) if mode in USES_CURRENT else None
        l_desired = interaction_matrix(s_star, target.depth_m) if mode in USES_DESIRED else None
        if mode is JacobianMode.CONSTANT:
            return error, self._constant_control_matrix()
        return error, control_matrix(mode, l_current, l_desired, None)

    def _constant_control_matrix(self) -> FloatArray:
        """The constant strategy's ``M``: the frozen matrix's rows in the current pairing's
        order, pseudo-inverted; kept (:attr:`_constant_m`) while both stay the same."""
        assert self.l_constant is not None and self.pairing is not None
        kept = self._constant_m
        if kept is None or kept[0] is not self.l_constant or kept[1] != self.pairing:
            l_constant = np.roll(self.l_constant, -2 * self.pairing, axis=0)  # 2 rows per corner
            m = control_matrix(JacobianMode.CONSTANT, None, None, l_constant)
            m.setflags(write=False)
            kept = self._constant_m = (self.l_constant, self.pairing, m)
        return kept[2]

    @staticmethod
    def _points3d_law(hand: Marker, target: Marker) -> tuple[FloatArray, FloatArray]:
        """``(e, M)`` on the measured 3-D corners (points3d); J at the current points, since
        only they (not the goal points) ride on the hand."""
        error = (hand.points_m - target.points_m).reshape(-1)
        return error, points3d_control_matrix(hand.points_m)
