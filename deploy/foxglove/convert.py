"""Project messages → Foxglove well-known messages: the functional core of ``umay view`` and
``umay export --foxglove``.

Nothing here opens a socket, a Zenoh session or a file: :class:`ViewState` takes the wire
messages of one run (:mod:`common.messages`), in the order they come, and returns what to show
as :class:`Out` records (topic, Foxglove message, log time). The live server
(:mod:`deploy.foxglove.node`) and the exporter (:mod:`deploy.foxglove.export`) feed it the same
way, so a recording opened in Foxglove shows what the live view showed. The messages are built
by concern: :mod:`~deploy.foxglove.topics` (the channels, frame names and JSON schemas),
:mod:`~deploy.foxglove.transforms` (time stamps and the transform tree),
:mod:`~deploy.foxglove.image` (images, calibration, overlay), :mod:`~deploy.foxglove.scene`
(the 3-D scene) and :mod:`~deploy.foxglove.style` (colours).

Time: every message is stamped with the **simulation** time of the data it shows
(``header.sim_time_s``), and that is also its log time, so plots and the timeline are in
simulated seconds, live and in an export alike.

Frames (Foxglove's transform tree): ``world`` (z up, as Foxglove's 3-D panel expects),
``base`` (DH frame 0, the arm base: x forward, y up, z right; turned +90° about x from
``world``), ``dh_1`` … ``dh_6`` (each child of the previous one, by the DH link transform of its
joint), ``end_effector`` (= ``dh_6``), ``hand_marker`` (the green square on the back of the
hand), ``camera`` (the optical frame where the controller *assumes* the camera is: its
calibration) and ``camera_true`` (the true mount the simulator renders from; separately
labelled). The images and vision's 3-D corners are in ``camera``.

Ground truth: the simulator's truth topic (:class:`common.messages.SimTruth`) is shown only
on its own topic (:data:`~deploy.foxglove.topics.TRUTH_SCENE`), labelled as ground truth. The
view is an observer: it never publishes anything back to the system.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from foxglove.messages import FrameTransforms, JointState, JointStates, Log, LogLevel

from common import keys
from common.config import Scenario
from common.keys import SERVICES
from common.kinematics import FloatArray
from common.messages import (
    DepthFrame,
    EndEffectorTwist,
    Features,
    JointVelocityCommand,
    RgbFrame,
    ServiceStatus,
    SimTruth,
)
from common.messages import JointState as UmayJointState
from common.runs import RunVerdict, RunWatch
from deploy.foxglove.image import (
    calibration,
    compressed_image,
    depth_image,
    image_annotations,
)
from deploy.foxglove.scene import measured_markers, static_scene, truth_scene
from deploy.foxglove.topics import (
    ANNOTATIONS,
    CALIBRATION,
    COLOUR_IMAGE,
    DEPTH_IMAGE,
    FEATURE_ERROR,
    JOINT_COMMAND,
    JOINT_NAMES,
    JOINT_STATES,
    LOG,
    PHASE,
    PHASES,
    SCENE,
    TRANSFORMS,
    TRUTH_SCENE,
    TWIST,
)
from deploy.foxglove.transforms import arm_transforms, camera_transforms, stamp, time_ns

TRAIL_MAX_POINTS = 3000  # the hand-marker centre's trail (the thesis's white dots)
TRAIL_MIN_STEP_PX = 1.0  # a dot is added once the centre has moved this far from the last
STATIC_PERIOD_S = 1.0  # the fixed scene is sent again this often (sim s), for late clients
RESTART_BACK_S = 1.0  # simulated time going back by more than this: a new run began
# The overlay draws the controller's goal of a twist at most this much (simulated s) older than
# the features it is drawn on: an older one belongs to a controller that has gone silent. A
# newer one is drawn: a view that lags shows a frame after the controller has answered later ones.
GOAL_MAX_AGE_S = 0.5


@dataclass(frozen=True)
class Out:
    """One message to show: ``message`` is a Foxglove message, or a dict for a JSON topic."""

    topic: str
    message: Any
    log_time_ns: int


def joint_states(names: tuple[str, ...], position, velocity, t_s: float) -> JointStates:
    return JointStates(
        timestamp=stamp(t_s),
        joints=[
            JointState(
                name=n,
                position=None if position is None else float(position[i]),
                velocity=None if velocity is None else float(velocity[i]),
            )
            for i, n in enumerate(names)
        ],
    )


def phase_of(twist: EndEffectorTwist) -> str:
    if twist.converged:
        return "converged"
    return "servoing" if twist.valid else "holding"


def phase_key(twist: EndEffectorTwist) -> tuple[str, str]:
    """What a change of the controller's phase is judged by: the phase and the hold reason."""
    return phase_of(twist), twist.hold_reason


def status_log(status: ServiceStatus | None, service: str, t_s: float) -> Log:
    """One line per service and status query: its state, rates and processing time."""
    if status is None:
        return Log(
            timestamp=stamp(t_s),
            level=LogLevel.Warning,
            message="no status answer",
            name=service,
        )
    rates = ", ".join(
        f"{k.rsplit('/', 1)[-1]} {s.rate_hz:.1f} Hz" for k, s in sorted(status.published.items())
    )
    p50 = status.processing_ms_p50
    parts = [
        status.state + (f" ({status.degraded_reason})" if status.degraded_reason else ""),
        f"pid {status.pid}",
        f"up {status.uptime_s:.0f} s",
    ]
    if rates:
        parts.append(f"out: {rates}")
    if p50 is not None:
        parts.append(f"processing p50 {p50:.2f} ms")
    if status.rejected:
        parts.append(f"rejected {status.rejected}: {status.last_rejection}")
    level = LogLevel.Info if status.state == "running" else LogLevel.Warning
    return Log(timestamp=stamp(t_s), level=level, message="; ".join(parts), name=service)


def status_logs(statuses: list[ServiceStatus], t_s: float) -> list[Out]:
    """A log line for each of the four services (a warning for one that did not answer)."""
    by_name = {s.service: s for s in statuses}
    return [Out(LOG, status_log(by_name.get(s), s, t_s), time_ns(t_s)) for s in SERVICES]


@dataclass
class ViewState:
    """The view of one run: feed it the run's messages in order (``on_*``), show what they
    return. State: the hand-marker trail, the last features, the controller's last phase, when
    the fixed scene was last sent and the newest simulation time seen."""

    scenario: Scenario
    trail_max: int = TRAIL_MAX_POINTS
    trail_px: list[tuple[float, float]] = field(default_factory=list)
    last_error_px_rms: float | None = None
    last_phase: tuple[str, str] | None = None
    goal: tuple[float, FloatArray] | None = None  # the newest twist's sim time and s* (desired_px)
    static_sent_s: float | None = None
    sim_time_s: float = 0.0
    runs: RunWatch = field(default_factory=RunWatch)  # the sim's runs seen, kept across runs

    @property
    def run(self) -> int:
        """The sim's run in progress (Header.run; 0: none stamped seen)."""
        return self.runs.current or 0

    def desired_px(self, sim_time_s: float) -> FloatArray | None:
        """The controller's s* for the camera frame taken at ``sim_time_s`` (4×2 px, row i where
        hand corner i is driven): the newest twist's, unless it is more than
        :data:`GOAL_MAX_AGE_S` older (the controller silent). A frame's features come before its
        twist, and the live view shows some frames only and may lag, so the overlay on a frame
        may show the goal of a few frames before or after it: the same while the target is
        still; for a frame after vision labelled a marker afresh, in another corner order."""
        if self.goal is None or sim_time_s - self.goal[0] > GOAL_MAX_AGE_S:
            return None
        return self.goal[1]

    def continued(self, message: Any) -> ViewState | None:
        """This state, a fresh one when ``message`` begins a new run, or None when it is left
        over from a run that is over (sent before the sim restarted, come late: shown, it would
        start that old run's view again); the one rule the live view and the export follow.
        A stamped message is judged by its run (:class:`common.runs.RunWatch`, as the services
        judge theirs: a stop may carry any time), one without by simulated time gone back more
        than :data:`RESTART_BACK_S`. Kept, this state would hold the old run's trail and clock,
        and send no fixed scene or calibration until the new run passed the old one's time."""
        header = getattr(message, "header", None)
        if header is None:
            return self
        if header.run:
            followed = self.runs.current is not None  # a run seen before this one's message
            verdict = self.runs.see(header.run)
            if verdict is RunVerdict.OVER:
                return None
            if verdict is RunVerdict.SAME:
                return self
            if followed:  # a new run after another
                return self._fresh()
        if header.sim_time_s < self.sim_time_s - RESTART_BACK_S:
            return self._fresh()
        return self

    def _fresh(self) -> ViewState:
        return ViewState(self.scenario, self.trail_max, runs=self.runs)

    def phase_changes(self, twist: EndEffectorTwist) -> bool:
        """Whether ``twist`` changes the controller's phase or hold reason (logged, always)."""
        return phase_key(twist) != self.last_phase

    def _advance(self, t_s: float) -> None:
        self.sim_time_s = max(self.sim_time_s, t_s)

    def fixed(self, t_s: float) -> list[Out]:
        """The fixed scene, the camera frames and the calibration, once per
        :data:`STATIC_PERIOD_S` (and on the first call)."""
        if self.static_sent_s is not None and t_s - self.static_sent_s < STATIC_PERIOD_S:
            return []
        self.static_sent_s = t_s
        ns = time_ns(t_s)
        k = self.scenario.camera.intrinsics()
        return [
            Out(SCENE, static_scene(self.scenario, t_s), ns),
            Out(CALIBRATION, calibration(k, t_s), ns),
        ]

    def on_rgb(self, frame: RgbFrame, jpeg_quality: int = 85) -> list[Out]:
        t = frame.header.sim_time_s
        self._advance(t)
        return [Out(COLOUR_IMAGE, compressed_image(frame, jpeg_quality), time_ns(t))]

    def on_depth(self, frame: DepthFrame) -> list[Out]:
        t = frame.header.sim_time_s
        self._advance(t)
        return [Out(DEPTH_IMAGE, depth_image(frame), time_ns(t))]

    def on_joint_state(self, js: UmayJointState) -> list[Out]:
        t = js.header.sim_time_s
        self._advance(t)
        tf = FrameTransforms(
            transforms=[*arm_transforms(np.array(js.position_rad), t),
                        *camera_transforms(self.scenario, t)]
        )  # fmt: skip
        ns = time_ns(t)
        states = joint_states(JOINT_NAMES, js.position_rad, js.velocity_rad_s, t)
        return [*self.fixed(t), Out(TRANSFORMS, tf, ns), Out(JOINT_STATES, states, ns)]

    def on_features(self, features: Features) -> list[Out]:
        t = features.header.sim_time_s
        self._advance(t)
        ns = time_ns(t)
        hand = features.hand
        if hand.usable:
            u, v = np.mean(np.asarray(hand.corners_px, dtype=float), axis=0)
            last = self.trail_px[-1] if self.trail_px else None
            if last is None or math.hypot(u - last[0], v - last[1]) >= TRAIL_MIN_STEP_PX:
                self.trail_px.append((float(u), float(v)))
            del self.trail_px[: max(0, len(self.trail_px) - self.trail_max)]
        desired = self.desired_px(features.header.sim_time_s)
        error: dict[str, Any] = {
            "sim_time_s": t,
            "frame_seq": features.header.frame_seq,
            "error_px": [],
            "error_px_rms": None,
            "hand_state": hand.state,
            "target_state": features.target.state,
        }
        rms = None
        if desired is not None and hand.usable:
            e = np.asarray(hand.corners_px, dtype=float) - desired  # rows paired by the controller
            rms = float(np.sqrt(np.mean(e**2)))
            error.update(error_px=e.reshape(-1).tolist(), error_px_rms=rms)
        self.last_error_px_rms = rms
        ann = image_annotations(features, desired, self.trail_px, rms)
        return [
            Out(ANNOTATIONS, ann, ns),
            Out(FEATURE_ERROR, error, ns),
            Out(SCENE, measured_markers(features), ns),
        ]

    def note_goal(self, twist: EndEffectorTwist) -> None:
        """Keep ``twist``'s goal for the overlay (:meth:`desired_px`). The live view calls it on
        every twist, also those its rate limit does not show: a lockstep run's frames come
        faster than the limit, and the goal of a twist left out would be frames old."""
        goal = None if twist.goal_px is None else np.array(twist.goal_px, dtype=float)
        self.goal = None if goal is None else (twist.header.sim_time_s, goal)

    def on_twist(self, twist: EndEffectorTwist) -> list[Out]:
        t = twist.header.sim_time_s
        self._advance(t)
        self.note_goal(twist)
        ns = time_ns(t)
        phase = phase_of(twist)
        out = [
            Out(
                TWIST,
                {
                    "sim_time_s": t,
                    "frame_seq": twist.header.frame_seq,
                    "linear_m_s": list(twist.linear_m_s),
                    "angular_rad_s": list(twist.angular_rad_s),
                    "speed_m_s": float(np.linalg.norm(twist.linear_m_s)),
                    "error_px_rms": twist.error_px_rms,
                },
                ns,
            ),
            Out(
                PHASE,
                {
                    "sim_time_s": t,
                    "phase": phase,
                    "phase_code": PHASES.index(phase),
                    "hold_reason": twist.hold_reason,
                    "mode": twist.mode,
                    "converged": twist.converged,
                    "lifted": twist.lifted,
                },
                ns,
            ),
        ]
        now = phase_key(twist)
        if now != self.last_phase:
            self.last_phase = now
            text = phase + (f": {twist.hold_reason}" if twist.hold_reason else "")
            level = LogLevel.Warning if phase == "holding" else LogLevel.Info
            log = Log(
                timestamp=stamp(t),
                level=level,
                message=f"{text} (frame {twist.header.frame_seq}, mode {twist.mode})",
                name="controller",
            )
            out.append(Out(LOG, log, ns))
        return out

    def on_joint_command(self, cmd: JointVelocityCommand) -> list[Out]:
        t = cmd.header.sim_time_s
        self._advance(t)
        states = joint_states(JOINT_NAMES, None, cmd.velocity_rad_s, t)
        return [Out(JOINT_COMMAND, states, time_ns(t))]

    def on_truth(self, truth: SimTruth) -> list[Out]:
        t = truth.header.sim_time_s
        self._advance(t)
        scene = truth_scene(truth, self.scenario.marker.size_m)
        return [Out(TRUTH_SCENE, scene, time_ns(t))]

    def on_message(self, suffix: str, message: Any, jpeg_quality: int = 85) -> list[Out]:
        """Route a message by its key relative to the prefix (``sim/rgb``, ...); keys the
        view does not show (``sim/timing``) give nothing."""
        if suffix == keys.RGB:
            return self.on_rgb(message, jpeg_quality)
        handler = self._handlers().get(suffix)
        return [] if handler is None else handler(message)

    def _handlers(self) -> dict[str, Any]:
        return {
            keys.DEPTH: self.on_depth,
            keys.JOINT_STATE: self.on_joint_state,
            keys.FEATURES: self.on_features,
            keys.TWIST: self.on_twist,
            keys.JOINT_COMMAND: self.on_joint_command,
            keys.TRUTH: self.on_truth,
        }


# The keys the view subscribes to (relative to the prefix) and their models.
VIEWED_KEYS: dict[str, type] = {
    keys.RGB: RgbFrame,
    keys.DEPTH: DepthFrame,
    keys.JOINT_STATE: UmayJointState,
    keys.FEATURES: Features,
    keys.TWIST: EndEffectorTwist,
    keys.JOINT_COMMAND: JointVelocityCommand,
    keys.TRUTH: SimTruth,
}
