"""``umay view`` / ``umay up --view`` / ``umay export --foxglove`` with real processes: a real
Foxglove WebSocket client (deploy.foxglove.client, over a socket), messages decoded with the
schemas the server advertised or the MCAP file holds, compared with what the services sent."""

from __future__ import annotations

import re
import select
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader

from common import kinematics as kin
from common.codec import DEFAULT_MAX_BYTES, decode
from common.messages import EndEffectorTwist, Features, JointState
from common.session import free_tcp_endpoint, open_session
from deploy.foxglove import convert, topics
from deploy.foxglove.client import FoxgloveClient, decoder, protobuf_class
from deploy.foxglove.transforms import rotation_from_quaternion, time_ns
from deploy.recording.channels import split_data_key
from deploy.recording.read import iter_messages
from tests.conftest import launch_umay_up

CORNER_TOL_PX = 0.01
EE_TOL_M = 1e-6


class Sent:
    """What the services published, by simulation time (ns), as the view would see it."""

    def __init__(self) -> None:
        self.features: dict[int, Features] = {}
        self.joints: dict[int, JointState] = {}
        self.twists: dict[int, EndEffectorTwist] = {}
        self.lock = threading.Lock()

    def add(self, message) -> None:
        with self.lock:
            table = {Features: self.features, JointState: self.joints}.get(
                type(message), self.twists
            )
            table[time_ns(message.header.sim_time_s)] = message

    def subscriber(self, model):
        def on_sample(sample) -> None:
            self.add(decode(sample.payload.to_bytes(), model, DEFAULT_MAX_BYTES))

        return on_sample

    def newest_twist_seq(self) -> int:
        with self.lock:
            return max((t.header.frame_seq for t in self.twists.values()), default=-1)


def pose_of(transforms, child: str) -> np.ndarray:
    by_child = {t.child_frame_id: t for t in transforms}
    pose = np.eye(4)
    while child != topics.BASE:
        t = by_child[child]
        r = rotation_from_quaternion(t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w)
        pose = (
            kin.homogeneous(r, np.array([t.translation.x, t.translation.y, t.translation.z])) @ pose
        )
        child = t.parent_frame_id
    return pose


def names(ann) -> set[str]:
    """The names of an overlay's points annotations."""
    return {dict((kv.key, kv.value) for kv in p.metadata).get("name") for p in ann.points}


def annotated(ann, name: str) -> np.ndarray:
    for p in ann.points:
        if dict((kv.key, kv.value) for kv in p.metadata).get("name") == name:
            return np.array([[q.x, q.y] for q in p.points])
    raise KeyError(name)


def stamp_ns(ts) -> int:
    return ts.seconds * 1_000_000_000 + ts.nanos


def check_content(decoded: dict[str, list[tuple[int, object]]], sent: Sent) -> dict[str, int]:
    """Every decoded message of a view against the services' messages at its simulation time:
    corners within CORNER_TOL_PX, the end effector within EE_TOL_M of forward kinematics, the
    image 640×480, the plots' values, the overlay's s* a goal of a twist near its time;
    how many of each were compared."""
    checked = {"annotations": 0, "tf": 0, "image": 0, "twist": 0, "depth": 0, "goal": 0}
    twist_times = sorted(sent.twists)
    max_age_ns = time_ns(convert.GOAL_MAX_AGE_S)  # the goals the overlay of a frame may show
    for log_ns, ann in decoded[topics.ANNOTATIONS]:
        f = sent.features.get(log_ns)
        if f is None:
            continue
        assert stamp_ns(ann.texts[0].timestamp) == log_ns
        if f.hand.usable:
            hand = annotated(ann, "hand")
            assert np.abs(hand - np.array(f.hand.corners_px)).max() < CORNER_TOL_PX
        if f.target.usable:
            target = annotated(ann, "target")
            assert np.abs(target - np.array(f.target.corners_px)).max() < CORNER_TOL_PX
        # s* drawn is a twist's goal from GOAL_MAX_AGE_S before the frame on (a view that lags
        # may draw a newer one); the callers ask for enough frames drawn with one.
        if "desired" in names(ann):
            near = [sent.twists[t] for t in twist_times if t >= log_ns - max_age_ns]
            goals = [np.array(t.goal_px) for t in near if t.goal_px is not None]
            desired = annotated(ann, "desired")
            assert min(np.abs(desired - g).max() for g in goals) < CORNER_TOL_PX
            checked["goal"] += 1
        checked["annotations"] += 1
    for log_ns, tf in decoded[topics.TRANSFORMS]:
        js = sent.joints.get(log_ns)
        if js is None:
            continue
        fk = kin.forward_kinematics(np.array(js.position_rad))
        ee = pose_of(tf.transforms, topics.EE)
        assert np.abs(ee[:3, 3] - fk[:3, 3]).max() < EE_TOL_M
        assert np.abs(ee[:3, :3] - fk[:3, :3]).max() < 1e-9
        checked["tf"] += 1
    for _log_ns, img in decoded[topics.COLOUR_IMAGE]:
        rgb = cv2.imdecode(np.frombuffer(img.data, np.uint8), cv2.IMREAD_COLOR)
        assert rgb.shape == (480, 640, 3) and img.format == "jpeg"
        checked["image"] += 1
    for _log_ns, depth in decoded[topics.DEPTH_IMAGE]:
        assert (depth.width, depth.height, depth.encoding) == (640, 480, "32FC1")
        d = np.frombuffer(depth.data, np.float32)
        assert d.size == 640 * 480 and 0.3 < np.median(d[d > 0]) < 3.0
        checked["depth"] += 1
    for log_ns, tw in decoded[topics.TWIST]:
        sent_tw = sent.twists.get(log_ns)
        if sent_tw is None:
            continue
        assert tw["linear_m_s"] == sent_tw.linear_m_s
        assert tw["angular_rad_s"] == sent_tw.angular_rad_s
        assert tw["error_px_rms"] == sent_tw.error_px_rms
        checked["twist"] += 1
    return checked


def announced_view_port(proc: subprocess.Popen, timeout_s: float) -> int:
    """The port in ``umay up``'s line "Foxglove view at ws://HOST:PORT", read off its output."""
    said: list[str] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 0.5)
        if ready:
            line = proc.stdout.readline()
            assert line, "umay up ended: " + "".join(said)
            said.append(line)
            found = re.search(r"Foxglove view at ws://127\.0\.0\.1:(\d+)", line)
            if found:
                return int(found.group(1))
    raise AssertionError("umay up did not say where the view serves: " + "".join(said))


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """``umay up --view`` (lockstep) and a Zenoh listener on the same data keys."""
    tmp = tmp_path_factory.mktemp("view")
    # Port 0: the view takes a free port, and `umay up` says which.
    proc, keys, endpoint = launch_umay_up(tmp / "logs", "lockstep", "--view", "--view-port", "0")
    port = announced_view_port(proc, 60)
    session = open_session(connect=[endpoint])
    sent = Sent()
    subs = [
        session.declare_subscriber(keys.features, sent.subscriber(Features)),
        session.declare_subscriber(keys.joint_state, sent.subscriber(JointState)),
        session.declare_subscriber(keys.twist, sent.subscriber(EndEffectorTwist)),
    ]
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and sent.newest_twist_seq() < 3:
            assert proc.poll() is None, proc.stdout.read()
            time.sleep(0.2)
        assert sent.newest_twist_seq() >= 3, "the loop did not start"
        yield f"ws://127.0.0.1:{port}", sent, keys, tmp
    finally:
        for s in subs:
            s.undeclare()
        session.close()
        proc.terminate()
        proc.wait(30)


def collect(client: FoxgloveClient) -> dict[str, list[tuple[int, object]]]:
    out: dict[str, list[tuple[int, object]]] = {}
    for topic in {ch["topic"] for ch in client.channels.values()}:
        decode_one = decoder(client.channel(topic))
        out[topic] = [(r.log_time_ns, decode_one(r.payload)) for r in client.messages(topic)]
    return out


@pytest.mark.xdist_group("live_view")  # the module's live run is started once per worker
def test_live_view_shows_the_run(live) -> None:
    url, sent, _keys, tmp = live
    client = FoxgloveClient(url).start()
    try:
        enough = client.wait_for(
            lambda cl: all(cl.counts.get(t, 0) >= n for t, n in (
                (topics.ANNOTATIONS, 15), (topics.TRANSFORMS, 15), (topics.COLOUR_IMAGE, 3),
                (topics.DEPTH_IMAGE, 1), (topics.TWIST, 15), (topics.LOG, 4), (topics.SCENE, 5),
            )),
            90,
        )  # fmt: skip
        assert enough, client.counts
    finally:
        client.stop()
    assert client.subprotocol in ("foxglove.sdk.v1", "foxglove.websocket.v1")
    advertised = {ch["topic"]: ch for ch in client.channels.values()}
    assert advertised[topics.COLOUR_IMAGE]["schemaName"] == "foxglove.CompressedImage"
    assert advertised[topics.COLOUR_IMAGE]["encoding"] == "protobuf"
    assert advertised[topics.TWIST]["encoding"] == "json"
    time.sleep(0.5)  # the Zenoh listener may be a message behind the view
    checked = check_content(collect(client), sent)
    assert checked["annotations"] >= 10 and checked["tf"] >= 10 and checked["twist"] >= 10
    # The goal drawn on most frames, though a lockstep run's twists come faster than it shows.
    assert checked["goal"] >= 0.5 * checked["annotations"], checked
    assert checked["image"] >= 3 and checked["depth"] >= 1
    logs = [decoder(advertised[topics.LOG])(r.payload) for r in client.messages(topics.LOG)]
    assert {lg.name for lg in logs} >= {"sim", "vision", "controller", "actuation"}
    # Waiting for the view to serve opened no connection of its own (the server would log it).
    view_log = (tmp / "logs" / "view.log").read_text()
    assert "umay view: Foxglove WebSocket at ws://" in view_log
    assert "handshake" not in view_log.lower(), view_log


@pytest.mark.xdist_group("live_view")  # the module's live run is started once per worker
def test_clients_that_vanish_or_stall_do_not_slow_the_loop(live) -> None:
    url, sent, _keys, _tmp = live
    # A client that disconnects mid-stream, without a close handshake.
    rude = FoxgloveClient(url).start()
    assert rude.wait_for(lambda cl: cl.counts.get(topics.COLOUR_IMAGE, 0) >= 2, 60)
    rude.stop(0.0)
    # A client that stops reading: the server's queue for it fills, the socket backs up.
    slow = FoxgloveClient(url, keep=False).start()
    assert slow.wait_for(lambda cl: cl.counts.get(topics.COLOUR_IMAGE, 0) >= 1, 60)
    slow.paused.set()
    # The loop goes on at the rate it had.
    seq0, t0 = sent.newest_twist_seq(), time.monotonic()
    time.sleep(6.0)
    stalled_rate = (sent.newest_twist_seq() - seq0) / (time.monotonic() - t0)
    slow.stop(0.0)
    seq1, t1 = sent.newest_twist_seq(), time.monotonic()
    time.sleep(4.0)
    free_rate = (sent.newest_twist_seq() - seq1) / (time.monotonic() - t1)
    print(f"loop rate with a stalled client {stalled_rate:.1f} frames/s, after {free_rate:.1f}")
    assert stalled_rate > 0.5 * free_rate > 0, (stalled_rate, free_rate)
    # And the view still serves a well-behaved client.
    good = FoxgloveClient(url, keep=False).start()
    try:
        assert good.wait_for(lambda cl: cl.counts.get(topics.ANNOTATIONS, 0) >= 5, 60), good.counts
    finally:
        good.stop()


def test_a_port_in_use_is_refused_with_a_clear_message() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = subprocess.run(
            [sys.executable, "-m", "deploy", "view", "--port", str(port), "--prefix", "test/none",
             "--connect", "tcp/127.0.0.1:9"],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
    assert proc.returncode == 1, proc.stderr
    assert f"cannot serve on 127.0.0.1:{port}" in proc.stderr
    assert "in use" in proc.stderr


def test_export_writes_the_view_channels_from_a_recording(tmp_path: Path) -> None:
    run = tmp_path / "run.mcap"
    out = tmp_path / "foxglove.mcap"
    proc = subprocess.run(
        [sys.executable, "-m", "deploy", "run", "--timeout", "1.0", "--quiet", "--record",
         str(run), "--prefix", f"test/export{time.monotonic_ns()}", "--listen",
         free_tcp_endpoint(), "--log-dir", str(tmp_path / "logs")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert run.is_file(), proc.stderr
    proc = subprocess.run(
        [sys.executable, "-m", "deploy", "export", str(run), "--foxglove", str(out)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    sent = Sent()
    for topic, _log, _pub, payload in iter_messages(run):
        split = split_data_key(topic)
        if split and split[2] in (Features, JointState, EndEffectorTwist):
            sent.add(decode(payload, split[2], DEFAULT_MAX_BYTES))
    decoded: dict[str, list[tuple[int, object]]] = {}
    with out.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        encodings = {ch.topic: ch.message_encoding for ch in summary.channels.values()}
        classes = {}
        for schema, channel, message in reader.iter_messages():
            if channel.message_encoding == "json":
                value = __import__("json").loads(message.data)
            else:
                if schema.id not in classes:
                    assert schema.encoding == "protobuf"
                    classes[schema.id] = protobuf_class(schema.name, schema.data)
                value = classes[schema.id].FromString(message.data)
            decoded.setdefault(channel.topic, []).append((message.log_time, value))
    assert (
        encodings[topics.COLOUR_IMAGE] == "protobuf" and encodings[topics.FEATURE_ERROR] == "json"
    )
    assert set(decoded) >= {
        topics.COLOUR_IMAGE,
        topics.DEPTH_IMAGE,
        topics.ANNOTATIONS,
        topics.TRANSFORMS,
        topics.SCENE,
        topics.TWIST,
        topics.PHASE,
        topics.JOINT_STATES,
        topics.LOG,
    }
    checked = check_content(decoded, sent)
    assert checked["annotations"] >= 20 and checked["tf"] >= 20 and checked["twist"] >= 20
    assert checked["goal"] >= checked["annotations"] - 1  # all but the first, before a twist
    # Every frame exported (no rate limit), log times = simulation time.
    times = {topic: {t for t, _ in decoded[topic]} for topic in decoded}
    assert times[topics.ANNOTATIONS] == set(sent.features)
    assert times[topics.TRANSFORMS] == set(sent.joints)
    assert times[topics.TWIST] == set(sent.twists)
    assert times[topics.COLOUR_IMAGE] >= set(sent.features)
    assert max(t for t, _ in decoded[topics.TRANSFORMS]) <= 2_000_000_000
