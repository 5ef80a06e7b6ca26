"""The view's pure converter (deploy.foxglove.convert): no Zenoh, no sockets, no files."""

from __future__ import annotations

import json
import re

import cv2
import numpy as np
import pytest

from common import kinematics as kin
from common.camera import project
from common.config import Scenario
from common.keys import FEATURES
from common.marker import Marker
from common.messages import (
    DepthFrame,
    EndEffectorTwist,
    Features,
    Header,
    ImageData,
    JointState,
    MarkerFeatures,
    RgbFrame,
    ServiceStatus,
)
from common.runs import REVIVE_AFTER
from deploy.foxglove import convert, image, topics
from deploy.foxglove.channels import TOPICS
from deploy.foxglove.client import protobuf_class
from deploy.foxglove.layout import layout_json
from deploy.foxglove.transforms import quaternion_xyzw, rotation_from_quaternion
from services.controller.convergence import feature_error_px_rms
from services.controller.goal import desired_observation


def header(t_s: float, seq: int = 0) -> Header:
    return Header(seq=seq, sim_time_s=t_s, send_time_s=1.0, frame_seq=seq)


def marker(points_m: np.ndarray, scenario: Scenario, state: str = "visible") -> MarkerFeatures:
    k = scenario.camera.intrinsics()
    return MarkerFeatures(
        state=state,
        corners_px=project(points_m, k).tolist(),
        depth_m=points_m[:, 2].tolist(),
        depth_sigma_m=[0.001] * 4,
        points_m=points_m.tolist(),
    )


def features(scenario: Scenario, t_s: float, shift_m: float = 0.0, seq: int = 0) -> Features:
    """Both markers seen in the camera frame: the target where the scenario puts it, the hand
    5 cm above it, moved along x by ``shift_m``."""
    t_cam_base = np.linalg.inv(scenario.camera.assumed_pose())
    target = kin.target_marker_pose(np.array(scenario.target.position), scenario.target.yaw)
    hand = kin.goal_marker_pose(target, 0.05)
    hand[:3, 3] += [shift_m, 0.0, 0.0]

    def in_cam(pose: np.ndarray) -> np.ndarray:
        corners = kin.marker_corners(pose, scenario.marker.size_m)
        return (t_cam_base @ np.c_[corners, np.ones(4)].T).T[:, :3]

    return Features(
        header=header(t_s, seq),
        intrinsics=scenario.camera.intrinsics(),
        hand=marker(in_cam(hand), scenario),
        target=marker(in_cam(target), scenario),
    )


def compose(transforms: list, child: str) -> np.ndarray:
    """The pose of ``child`` in ``base`` from decoded FrameTransform protobufs."""
    by_child = {t.child_frame_id: t for t in transforms}
    pose = np.eye(4)
    while child != "base":
        t = by_child[child]
        r = rotation_from_quaternion(t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w)
        tr = t.translation
        pose = kin.homogeneous(r, np.array([tr.x, tr.y, tr.z])) @ pose
        child = t.parent_frame_id
    return pose


def decoded(message) -> object:
    """A Foxglove SDK message through its own protobuf encoding and the schema it carries."""
    schema = message.get_schema()
    return protobuf_class(schema.name, schema.data).FromString(message.encode())


def test_quaternion_round_trip() -> None:
    rng = np.random.default_rng(0)
    for _ in range(200):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        r = rotation_from_quaternion(*q)
        back = quaternion_xyzw(r)
        assert np.allclose(rotation_from_quaternion(*back), r, atol=1e-12)
        assert back[3] >= 0


def test_transforms_compose_to_forward_kinematics(scenario: Scenario) -> None:
    q = np.array([-1.2, 0.8, -1.5, 1.3, 0.4, -0.2])
    js = JointState(header=header(1.5), position_rad=q.tolist(), velocity_rad_s=[0.1] * 6)
    outs = {o.topic: o for o in convert.ViewState(scenario).on_joint_state(js)}
    tf = decoded(outs[topics.TRANSFORMS].message)
    ee = compose(list(tf.transforms), topics.EE)
    assert np.allclose(ee, kin.forward_kinematics(q), atol=1e-12)
    marker_pose = compose(list(tf.transforms), topics.HAND_MARKER)
    assert np.allclose(marker_pose, kin.forward_kinematics(q) @ kin.hand_marker_in_ee(), atol=1e-12)
    assert np.allclose(compose(list(tf.transforms), topics.CAMERA_TRUE), scenario.camera.pose())
    assert outs[topics.TRANSFORMS].log_time_ns == 1_500_000_000
    assert {t.timestamp.seconds for t in tf.transforms} == {1}
    states = decoded(outs[topics.JOINT_STATES].message)
    assert [j.position for j in states.joints] == pytest.approx(q.tolist(), abs=0)
    # The fixed scene comes with the first joint state, then once per STATIC_PERIOD_S.
    assert topics.SCENE in outs and topics.CALIBRATION in outs


def goal_twist(t_s: float, seq: int, goal_px: np.ndarray | None) -> EndEffectorTwist:
    """A twist of the law for frame ``seq`` whose s* is ``goal_px`` (None: a hold)."""
    return EndEffectorTwist(
        header=header(t_s, seq), linear_m_s=[0.01, 0.0, 0.0], angular_rad_s=[0.0] * 3,
        valid=goal_px is not None, hold_reason="" if goal_px is not None else "target lost",
        mode="dynamic", error_px_rms=1.0, converged=False,
        goal_px=None if goal_px is None else goal_px.tolist(),
    )  # fmt: skip


def controller_goal(f: Features, scenario: Scenario, shift: int = 1) -> np.ndarray:
    """The desired corners above ``f``'s target, relabelled by ``shift`` as the controller may
    pair them (row i: where hand corner i goes)."""
    target = Marker.from_wire(f.target)
    desired = desired_observation(target, scenario.target.approach_height_m, f.intrinsics)
    return np.roll(desired.corners_px, -shift, axis=0)


def test_annotations_carry_vision_corners_the_controllers_goal_and_the_trail(
    scenario: Scenario,
) -> None:
    state = convert.ViewState(scenario, trail_max=3)
    for i in range(5):
        f = features(scenario, 0.1 * i, 0.01 * i, i)
        outs = {o.topic: o for o in state.on_features(f)}
        goal = controller_goal(f, scenario)
        state.on_twist(goal_twist(0.1 * i, i, goal))  # after the features, as they come
    ann = decoded(outs[topics.ANNOTATIONS].message)
    by_name = {dict((kv.key, kv.value) for kv in p.metadata)["name"]: p for p in ann.points}
    assert set(by_name) == {"hand", "target", "desired", "error", "trail"}
    for name, m in (("hand", f.hand), ("target", f.target)):
        got = np.array([[p.x, p.y] for p in by_name[name].points])
        assert np.array_equal(got, np.array(m.corners_px))
    # s* is the last twist's (frame 3's): the target is still, so frame 4's is the same.
    desired = controller_goal(features(scenario, 0.3, 0.03, 3), scenario)
    got = np.array([[p.x, p.y] for p in by_name["desired"].points])
    assert np.array_equal(got, desired)
    # Each error vector runs from hand corner i to the goal's row i: the controller's pairing.
    segments = np.array([[p.x, p.y] for p in by_name["error"].points]).reshape(4, 2, 2)
    assert np.array_equal(segments[:, 0], np.array(f.hand.corners_px))
    assert np.array_equal(segments[:, 1], desired)
    assert len(by_name["trail"].points) == 3  # capped
    trail_last = by_name["trail"].points[-1]
    assert [trail_last.x, trail_last.y] == pytest.approx(np.mean(f.hand.corners_px, axis=0))
    err = outs[topics.FEATURE_ERROR].message
    json.dumps(err)  # a JSON topic
    e = np.array(err["error_px"]).reshape(4, 2)
    hand = np.array(f.hand.corners_px)
    np.testing.assert_array_equal(e, hand - desired)
    assert err["error_px_rms"] == pytest.approx(feature_error_px_rms(hand, desired))
    texts = [t.text for t in ann.texts]
    assert texts[0] == "hand: visible" and texts[2].startswith("e: ")


def test_a_hidden_target_keeps_the_controllers_goal_and_error_on_the_overlay(
    scenario: Scenario,
) -> None:
    """While the hand hides the target the controller servos on its memory of it: the overlay
    shows that goal and the error to it, with the target itself not drawn. Without a twist (or
    one over GOAL_MAX_AGE_S away, or a hold) there is no goal to show."""
    seen = features(scenario, 0.0)
    lost = seen.model_copy(update={"target": seen.target.model_copy(update={"state": "lost"})})
    goal = controller_goal(seen, scenario)

    def names_and_rms(state: convert.ViewState, f: Features) -> tuple[set[str], float | None]:
        outs = {o.topic: o for o in state.on_features(f)}
        ann = decoded(outs[topics.ANNOTATIONS].message)
        names = {dict((kv.key, kv.value) for kv in p.metadata)["name"] for p in ann.points}
        return names, outs[topics.FEATURE_ERROR].message["error_px_rms"]

    state = convert.ViewState(scenario)
    assert names_and_rms(state, lost) == ({"hand", "trail"}, None)  # no twist yet
    state.on_twist(goal_twist(0.0, 0, goal))
    names, rms = names_and_rms(state, lost)
    assert names == {"hand", "desired", "error", "trail"} and rms is not None
    stale = lost.model_copy(update={"header": header(convert.GOAL_MAX_AGE_S + 0.01, 9)})
    assert names_and_rms(state, stale)[1] is None
    state.on_twist(goal_twist(0.1, 1, None))  # a hold: no goal
    assert names_and_rms(state, lost) == ({"hand", "trail"}, None)
    no_hand = seen.model_copy(update={"hand": seen.hand.model_copy(update={"state": "lost"})})
    state.on_twist(goal_twist(0.2, 2, goal))
    assert names_and_rms(state, no_hand)[1] is None


def test_images(scenario: Scenario) -> None:
    rng = np.random.default_rng(1)
    k = scenario.camera.intrinsics()
    rgb = np.zeros((k.height_px, k.width_px, 3), np.uint8)
    rgb[100:200, 50:150] = (200, 30, 20)
    frame = RgbFrame(header=header(2.0), intrinsics=k, rgb=ImageData.from_array(rgb))
    jpeg = decoded(image.compressed_image(frame, 95))
    assert jpeg.format == "jpeg" and jpeg.frame_id == topics.CAMERA
    back = cv2.cvtColor(cv2.imdecode(np.frombuffer(jpeg.data, np.uint8), 1), cv2.COLOR_BGR2RGB)
    assert back.shape == rgb.shape
    assert np.abs(back.astype(int) - rgb).mean() < 2.0
    depth = rng.uniform(0.4, 1.0, (k.height_px, k.width_px)).astype(np.float32)
    dframe = DepthFrame(header=header(2.0), intrinsics=k, depth_m=ImageData.from_array(depth))
    raw = decoded(image.depth_image(dframe))
    assert (raw.width, raw.height, raw.encoding, raw.step) == (k.width_px, k.height_px, "32FC1",
                                                               4 * k.width_px)  # fmt: skip
    assert np.array_equal(np.frombuffer(raw.data, np.float32).reshape(depth.shape), depth)


def test_phase_changes_are_logged_once(scenario: Scenario) -> None:
    state = convert.ViewState(scenario)

    def twist(t: float, valid: bool, converged: bool = False, reason: str = "") -> EndEffectorTwist:
        return EndEffectorTwist(
            header=header(t), linear_m_s=[0.01, 0.0, 0.0], angular_rad_s=[0.0] * 3, valid=valid,
            hold_reason=reason, mode="dynamic", error_px_rms=3.0, converged=converged,
        )  # fmt: skip

    # What the view's rate limit asks before it drops a twist: a change is never dropped.
    assert state.phase_changes(twist(0.0, True))
    runs = [
        state.on_twist(twist(0.0, True)),
        state.on_twist(twist(0.1, True)),
        state.on_twist(twist(0.2, False, reason="target lost")),
        state.on_twist(twist(0.3, True, converged=True)),
    ]
    logs = [[o.message for o in outs if o.topic == topics.LOG] for outs in runs]
    assert [len(x) for x in logs] == [1, 0, 1, 1]
    assert not state.phase_changes(twist(0.35, True, converged=True))
    assert state.phase_changes(twist(0.35, False, reason="hand lost"))
    assert "holding: target lost" in decoded(logs[2][0]).message
    phases = [next(o.message for o in outs if o.topic == topics.PHASE) for outs in runs]
    assert [p["phase_code"] for p in phases] == [0, 0, 1, 2]
    assert [p["lifted"] for p in phases] == [False] * 4
    lifted = twist(0.4, True).model_copy(update={"lifted": True})
    assert next(o.message for o in state.on_twist(lifted) if o.topic == topics.PHASE)["lifted"]
    tw = next(o.message for o in runs[0] if o.topic == topics.TWIST)
    assert tw["linear_m_s"] == [0.01, 0.0, 0.0] and tw["error_px_rms"] == 3.0


def stamped(message, run: int, t_s: float | None = None):
    """``message`` of the sim's run ``run`` (at ``t_s`` simulated, if given)."""
    update = {"run": run} if t_s is None else {"run": run, "sim_time_s": t_s}
    return message.model_copy(update={"header": message.header.model_copy(update=update)})


def test_a_new_run_is_told_by_time_going_back_and_a_fresh_state_sends_the_fixed_scene(
    scenario: Scenario,
) -> None:
    old = convert.ViewState(scenario)
    for k in range(3):
        old.on_features(features(scenario, 284.0 + k, shift_m=0.01 * k, seq=k))
    assert old.sim_time_s == 286.0 and len(old.trail_px) == 3
    # A message a little behind the newest: the same run.
    assert old.continued(features(scenario, 285.5)) is old
    assert old.fixed(286.0) != [] and old.fixed(286.5) == []  # not again within a second
    new = old.continued(features(scenario, 47.0))  # the sim restarted
    assert new is not None and new is not old and new.trail_px == []
    # Kept, the old state would send no fixed scene at 47 s; a fresh one does at once.
    assert old.fixed(47.0) == []
    assert {o.topic for o in new.fixed(47.0)} == {topics.SCENE, topics.CALIBRATION}


def test_a_sim_restarted_early_is_told_by_its_run_not_its_time(scenario: Scenario) -> None:
    """Killed at 0.8 s and restarted, the sim's time goes back less than a second: the run
    stamped on every message says it is another run all the same."""
    state = convert.ViewState(scenario)
    first = stamped(features(scenario, 0.8, seq=24), 11)
    assert state.continued(first) is state
    state.on_message(FEATURES, first)
    assert state.run == 11
    assert state.continued(stamped(first, 11, 0.7)) is state
    assert state.continued(stamped(first, 0, 0.2)) is state  # unstamped, not far back
    fresh = state.continued(stamped(first, 12, 0.03))  # a new run, 0.77 s back in time
    assert fresh is not None and fresh is not state


def test_runs_are_judged_as_the_services_judge_theirs(scenario: Scenario) -> None:
    """A stamped message is judged by its run alone: a stop of the run seen, stamped with an
    earlier time (a deadman stop once carried 0 s), does not start the view afresh; one of a
    run that a later one followed is left out, not taken for yet another run; and a stray
    message of a run never seen does not stop the live run's view for good."""
    state = convert.ViewState(scenario)
    later = stamped(features(scenario, 1.87, seq=56), 3)
    assert state.continued(later) is state
    state.on_message(FEATURES, later)
    assert state.continued(stamped(later, 3, 0.0)) is state
    nxt = stamped(features(scenario, 0.03, seq=0), 4)
    fresh = state.continued(nxt)  # the next run's first message starts afresh
    assert fresh is not None and fresh is not state and fresh.runs is state.runs
    fresh.on_message(FEATURES, nxt)
    assert fresh.continued(later) is None  # run 3's, come late
    assert fresh.continued(stamped(nxt, 4, 0.07)) is fresh
    stray = fresh.continued(stamped(nxt, 99, 5.0))  # a run never seen takes the place...
    assert stray is not None and stray is not fresh
    stray.on_message(FEATURES, stamped(nxt, 99, 5.0))
    live = [stray.continued(stamped(nxt, 4, 0.1 + k / 30)) for k in range(REVIVE_AFTER)]
    assert live[:-1] == [None] * (REVIVE_AFTER - 1)  # ... until run 4 has kept coming
    assert live[-1] is not None and live[-1] is not stray


def test_status_logs_warn_of_a_silent_service() -> None:
    st = ServiceStatus(service="vision", pid=12, host="h", uptime_s=3.0, state="running")
    outs = convert.status_logs([st], 4.0)
    logs = {decoded(o.message).name: decoded(o.message) for o in outs}
    assert set(logs) == {"sim", "vision", "controller", "actuation"}
    assert "running" in logs["vision"].message
    assert "no status answer" in logs["sim"].message


def test_every_view_topic_has_a_channel_and_the_layout_is_up_to_date() -> None:
    from pathlib import Path

    path = Path(topics.__file__).with_name("layout.json")
    assert path.read_text() == layout_json(), "regenerate: python -m deploy.foxglove.layout"
    names = {v for k, v in vars(topics).items() if k.isupper() and isinstance(v, str)
             and v.startswith("/")}  # fmt: skip
    assert names == set(TOPICS)
    # The layout names only topics the view has (and some: it is not empty).
    named = set(re.findall(r'"(/[a-z_]+(?:/[a-z_]+)*)[".]', path.read_text()))
    assert named and named <= set(TOPICS), named - set(TOPICS)
