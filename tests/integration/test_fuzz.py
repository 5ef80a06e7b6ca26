"""Fuzz every key each service subscribes to while the loop runs (lockstep, default scenario).

10,000+ random and mutated payloads: random bytes, truncated messages, wrong types, NaN, huge
arrays, images whose size does not match their shape, and valid-looking messages with values
out of range; camera frames both as plain msgpack and in the codec's raw frame layout (bad
prefix, version or header length, cut pixels, wrong image descriptions, bad header fields,
frames by reference whose reference is garbage or names another image).
Every one must be rejected and counted; no service may exit; the run converges.

At its own gain the default scenario converges in about as much wall time as the fuzzing
takes, so the services could stop before their counts are read; a quarter of the gain makes
the approach about three times as long and keeps the loop servoing through the fuzzing.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
from zenoh import CongestionControl

from common.camera import CameraIntrinsics
from common.codec import (
    DEFAULT_MAX_BYTES,
    FRAME_ALIGN,
    FRAME_MAGIC,
    FRAME_MAX_BYTES,
    FRAME_PREFIX,
    FRAME_VERSION,
    FRAME_VERSION_REF,
    MessageError,
    decode,
)
from common.config import load_scenario
from common.frame_ring import FrameRef
from common.keys import SERVICES, Keys
from common.messages import (
    DepthFrame,
    EndEffectorTwist,
    Features,
    Header,
    ImageData,
    JointState,
    JointVelocityCommand,
    MarkerFeatures,
    RgbFrame,
)
from common.runtime import parse_overrides
from common.session import free_tcp_endpoint, open_session
from deploy.launch.run import run_once
from deploy.launch.status import collect
from tests.prefixes import unique_keys

H = Header(seq=0, sim_time_s=0.0, send_time_s=0.0, frame_seq=0)
K = CameraIntrinsics.from_fov(32, 24, 57.0)
M = MarkerFeatures(
    state="visible",
    corners_px=[[10.0, 8.0], [20.0, 8.0], [20.0, 18.0], [10.0, 18.0]],
    depth_m=[0.5] * 4,
    depth_sigma_m=[0.001] * 4,
    points_m=[[-0.01, -0.01, 0.5], [0.01, -0.01, 0.5], [0.01, 0.01, 0.5], [-0.01, 0.01, 0.5]],
)
FRAMES = ("rgb", "depth")
TEMPLATES = {
    "rgb": RgbFrame(
        header=H, intrinsics=K, rgb=ImageData.from_array(np.zeros((24, 32, 3), np.uint8))
    ),
    "depth": DepthFrame(
        header=H, intrinsics=K, depth_m=ImageData.from_array(np.zeros((24, 32), np.float32))
    ),
    "joint_state": JointState(header=H, position_rad=[0.1] * 6, velocity_rad_s=[0.0] * 6),
    "features": Features(header=H, intrinsics=K, hand=M, target=M),
    "twist": EndEffectorTwist(
        header=H,
        linear_m_s=[0.0] * 3,
        angular_rad_s=[0.0] * 3,
        valid=True,
        mode="dynamic",
        error_px_rms=1.0,
        converged=False,
    ),
    "joint_command": JointVelocityCommand(header=H, velocity_rad_s=[0.0] * 6),
}


def _floats(d: object) -> list[tuple[object, object]]:
    """(container, index) of every float in a nested dict/list."""
    out = []
    items = d.items() if isinstance(d, dict) else enumerate(d) if isinstance(d, list) else []
    for k, v in items:
        if isinstance(v, float):
            out.append((d, k))
        else:
            out.extend(_floats(v))
    return out


def frame_layout(data: dict, version: int = FRAME_VERSION, head_len: int | None = None) -> bytes:
    """``data`` (a frame as plain data) in the codec's frame layout: header map, then pixels."""
    image = next(k for k in ("rgb", "depth_m") if k in data)
    pixels = data[image].get("data", b"") if isinstance(data[image], dict) else b""
    head_map = dict(data)
    if isinstance(data[image], dict):
        head_map[image] = {k: v for k, v in data[image].items() if k != "data"}
    head = msgpack.packb(head_map, use_bin_type=True)
    used = FRAME_PREFIX.size + len(head)
    pad = bytes(-(-used // FRAME_ALIGN) * FRAME_ALIGN - used)
    n = len(head) if head_len is None else head_len
    return FRAME_PREFIX.pack(FRAME_MAGIC, version, n) + head + pad + bytes(pixels)


def mutate_frame_layout(template: dict, rng: np.random.Generator) -> bytes:
    """One invalid payload in the raw frame layout (what the sim sends)."""
    kind = int(rng.integers(0, 7))
    valid = frame_layout(template)
    if kind == 0:  # the magic, then garbage
        return FRAME_MAGIC + rng.bytes(int(rng.integers(0, 200)))
    if kind == 1:  # cut anywhere, pixels included
        return valid[: int(rng.integers(0, len(valid) - 1))]
    if kind == 2:  # a layout version that does not exist, or a header length that lies
        if rng.random() < 0.5:
            return frame_layout(template, version=int(rng.integers(3, 1 << 16)))
        return frame_layout(template, head_len=int(rng.integers(1 << 14, 1 << 32)))
    if kind == 3:  # pixels that do not match shape and dtype
        return valid[:-1] if rng.random() < 0.5 else valid + b"\x00"
    if kind == 6:  # by reference: pixels where the reference should be, or a reference to
        # another image than the header's
        if rng.random() < 0.5:
            return frame_layout(template, version=FRAME_VERSION_REF)
        image = next(k for k in ("rgb", "depth_m") if k in template)
        ref = FrameRef("h/b", "umay-frames-1-0", 1, 1, 128, (1, 1), "uint8").to_map()
        pixels = msgpack.packb(ref, use_bin_type=True)
        return frame_layout(
            {**template, image: {**template[image], "data": pixels}}, FRAME_VERSION_REF
        )
    data = msgpack.unpackb(msgpack.packb(template, use_bin_type=True), raw=False)
    image = next(k for k in ("rgb", "depth_m") if k in data)
    if kind == 4:  # a wrong image description
        # Each entry is wrong and one of the three is left out: never a valid description.
        data[image] = {"shape": [0, 0], "dtype": "float64", "strides": [1], "data": b""}
        del data[image][str(rng.choice(["shape", "dtype", "strides"]))]
        return frame_layout(data)
    return frame_layout(one_field_mutated(data, rng))


def mutate(template: dict, rng: np.random.Generator) -> bytes:
    """One invalid payload derived from a valid message."""
    if any(k in template for k in ("rgb", "depth_m")) and rng.random() < 0.5:
        return mutate_frame_layout(template, rng)
    # Huge arrays are few (2 %): each is about a megabyte on the wire.
    kind = 6 if rng.random() < 0.02 else int(rng.choice([0, 1, 2, 3, 4, 5, 7]))
    valid = msgpack.packb(template, use_bin_type=True)
    if kind == 0:
        return rng.bytes(int(rng.integers(0, 200)))
    if kind == 1:
        return valid[: int(rng.integers(0, len(valid) - 1))]
    data = msgpack.unpackb(valid, raw=False)
    return msgpack.packb(field_mutated(data, rng, kind), use_bin_type=True)


def one_field_mutated(data: dict, rng: np.random.Generator) -> dict:
    """``data`` with one field made invalid (a float, the sequence number, an extra field)."""
    return field_mutated(data, rng, int(rng.choice([2, 3, 4, 5, 7])))


def field_mutated(data: dict, rng: np.random.Generator, kind: int) -> dict:
    floats = _floats(data)
    container, index = floats[int(rng.integers(len(floats)))]
    if kind == 2:
        container[index] = "not a number"  # wrong type
    elif kind == 3:
        container[index] = [math.nan, math.inf, -math.inf][int(rng.integers(3))]
    elif kind == 4:
        container[index] = 1e9 * (1 if rng.random() < 0.5 else -1)  # out of range
    elif kind == 5:
        data["header"]["seq"] = -int(rng.integers(1, 1000))
    elif kind == 6:
        key = next(iter(k for k in data if k != "header"))
        data[key] = [0.0] * int(rng.integers(10_000, 100_000))  # huge array
    else:
        data["surprise"] = 1  # unknown field
    for image in ("rgb", "depth_m"):
        if image in data and rng.random() < 0.5:
            data[image]["data"] = data[image]["data"][:-1]  # image size ≠ shape
    return data


def invalid_payload(name: str, template: dict, rng: np.random.Generator) -> bytes:
    """A mutation that the codec itself rejects (a rare mutation can stay valid: redraw)."""
    model = type(TEMPLATES[name])
    while True:
        payload = mutate(template, rng)
        try:
            decode(payload, model, FRAME_MAX_BYTES if name in FRAMES else DEFAULT_MAX_BYTES)
        except MessageError:
            return payload


SUBSCRIBERS = {  # key → services that subscribe to it
    "rgb": ["vision"],
    "depth": ["vision"],
    "joint_state": ["controller", "actuation"],
    "features": ["controller"],
    "twist": ["actuation"],
    "joint_command": ["sim"],
}


def key_of(keys: Keys, name: str) -> str:
    return {
        "rgb": keys.rgb,
        "depth": keys.depth,
        "joint_state": keys.joint_state,
        "features": keys.features,
        "twist": keys.twist,
        "joint_command": keys.joint_command,
    }[name]


def wait_until_listening(endpoint: str, timeout_s: float = 20.0) -> None:
    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            socket.create_connection((host, int(port)), timeout=0.2).close()
            return
        except OSError:
            time.sleep(0.05)
    raise TimeoutError(endpoint)


def test_fuzzing_every_input_while_servoing(tmp_path: Path) -> None:
    endpoint = free_tcp_endpoint()
    keys = unique_keys()
    overrides = ["controller.gain=0.25"]
    scenario = load_scenario(None, parse_overrides(overrides))
    results = []
    runner = threading.Thread(
        target=lambda: results.append(
            run_once(
                None, scenario, overrides, keys.prefix, tmp_path / "logs",
                listen=endpoint, quiet=True,
            )
        )
    )  # fmt: skip
    runner.start()
    wait_until_listening(endpoint)
    session = open_session(connect=[endpoint])
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            views = {v.name: v for v in collect(session, keys, 0.3)}
            if all(views.get(n) and views[n].alive and views[n].status for n in SERVICES):
                break
        rng = np.random.default_rng(2024)
        templates = {n: m.model_dump() for n, m in TEMPLATES.items()}
        sent = dict.fromkeys(SUBSCRIBERS, 0)
        total = 10_500
        started = time.monotonic()
        for i in range(total):
            name = list(SUBSCRIBERS)[i % len(SUBSCRIBERS)]
            payload = invalid_payload(name, templates[name], rng)
            # Blocking puts: every payload must arrive, so the counts can be compared exactly.
            session.put(key_of(keys, name), payload, congestion_control=CongestionControl.BLOCK)
            sent[name] += 1
        expected = dict.fromkeys(SERVICES, 0)
        for name, count in sent.items():
            for service in SUBSCRIBERS[name]:
                expected[service] += count
        rejected = {}
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            views = {v.name: v for v in collect(session, keys, 0.5)}
            rejected = {
                n: views[n].status.rejected for n in SERVICES if views.get(n) and views[n].status
            }
            if rejected == expected:
                break
            time.sleep(0.5)
        print(
            f"sent {total} payloads in {time.monotonic() - started:.1f} s; "
            f"rejected per service {rejected}"
        )
        assert rejected == expected, f"the run still going: {runner.is_alive()}"
        assert all(views[n].alive for n in SERVICES)
    finally:
        runner.join(600)
        session.close()
    result = results[0]
    assert result.converged, result
    assert result.final_position_error_m < 0.005
    assert "service exited" not in result.detail
