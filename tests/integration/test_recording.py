"""Recording (MCAP) and replay, with the real services as OS processes over Zenoh on loopback.

One short lockstep run is recorded (``umay run --record``), read back with the ``mcap``
package, and replayed into vision, controller and actuation with ``umay replay --check``; a
changed controller gain must make the check fail. ``tests/data/reference.mcap`` (made by
``tests/data/make_reference.py``, see its docstring) is the committed regression recording:
vision and controller must reproduce it bit for bit.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from common.codec import FRAME_MAX_BYTES, decode, encode, is_by_reference
from common.keys import Keys
from common.messages import Header, JointState
from common.session import free_tcp_endpoint, open_session
from deploy.recording.channels import model_for_key
from deploy.recording.read import iter_messages, read_info
from deploy.recording.record import Recorder
from deploy.recording.replay import frame_seq_of
from tests.prefixes import unique_prefix

UMAY = [sys.executable, "-m", "deploy"]
REFERENCE = Path(__file__).resolve().parents[1] / "data" / "reference.mcap"
# 480×360: the smallest common size at which vision sees both markers from the start, so the
# controller servos (at 320×240 the red marker is reported occluded and the controller holds).
SMALL_RUN = ["camera.width_px=480", "camera.height_px=360", "run.timeout_s=0.5"]


def umay(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([*UMAY, *args], capture_output=True, text=True, timeout=timeout)


def small_run(prefix: str, log_dir: Path, *args: str) -> subprocess.CompletedProcess:
    """``umay run --quiet`` of the short :data:`SMALL_RUN` under ``prefix``, with ``args``;
    it stops at its short timeout (exit 1)."""
    sets = [a for item in SMALL_RUN for a in ("--set", item)]
    return umay(
        "run", "--quiet", *args, *sets,
        "--prefix", prefix, "--listen", free_tcp_endpoint(), "--log-dir", str(log_dir),
    )  # fmt: skip


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A short real run recorded to MCAP: (file, prefix)."""
    tmp = tmp_path_factory.mktemp("recording")
    out, prefix = tmp / "r.mcap", unique_prefix()
    proc = small_run(prefix, tmp / "logs", "--record", str(out))
    # The run stops at its (short) timeout: not converged, exit 1.
    assert proc.returncode == 1, f"stdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    assert out.exists(), proc.stderr
    return out, prefix


def replay(path: Path, service: str, tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    return umay(
        "replay", str(path), "--service", service, "--log-dir", str(tmp_path / "logs"), *args
    )


@pytest.mark.xdist_group("recording")  # the module's recording is made once per worker
def test_run_record_writes_an_indexed_zstd_mcap_with_every_data_key(
    recording: tuple[Path, str],
) -> None:
    path, prefix = recording
    keys = Keys(prefix)
    data_keys = [keys.rgb, keys.depth, keys.joint_state, keys.truth, keys.features, keys.twist]
    data_keys.append(keys.joint_command)
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None  # summary + index
        assert summary.chunk_indexes and {c.compression for c in summary.chunk_indexes} == {"zstd"}
        channels = {c.topic: c for c in summary.channels.values()}
        assert sorted(channels) == sorted(data_keys)
        counts = summary.statistics.channel_message_counts
        for key in data_keys:
            ch = channels[key]
            is_frame = key in (keys.rgb, keys.depth)  # a msgpack header, then raw pixels
            assert ch.message_encoding == ("umay-frame" if is_frame else "msgpack")
            schema = summary.schemas[ch.schema_id]
            model = model_for_key(keys, key)
            assert model is not None and schema.name == model.__name__
            assert schema.encoding == "jsonschema"
            assert json.loads(schema.data)["title"] == model.__name__
            assert counts[ch.id] > 0, key
        meta = {m.name: m.metadata for m in reader.iter_metadata()}["umay"]
        assert meta["prefix"] == prefix
        assert json.loads(meta["overrides_json"]) == SMALL_RUN
        assert "[controller]" in meta["scenario_toml"]
        # Every payload is the wire message: it decodes with its key's model. Camera frames,
        # which the sim sent by reference, are stored whole: a recording needs no ring.
        frames = 0
        for _schema, channel, message in reader.iter_messages():
            model = model_for_key(keys, channel.topic)
            assert not is_by_reference(message.data)
            decoded = decode(message.data, model, FRAME_MAX_BYTES)
            assert message.publish_time == round(decoded.header.send_time_s * 1e9)
            frames += channel.topic == keys.rgb
    assert frames >= 10  # 0.5 s at 30 Hz

    info = read_info(path)
    by_topic = {c.topic: c for c in info.channels}
    assert sorted(by_topic) == sorted(data_keys)
    for cid, n in counts.items():
        assert by_topic[summary.channels[cid].topic].count == n
    assert info.message_count == sum(counts.values())
    assert info.compression == ["zstd"] and info.chunk_count == len(summary.chunk_indexes)
    assert info.metadata["umay"]["prefix"] == prefix and info.damage is None
    assert 0.0 < info.duration_s < 60.0
    for frames_key in (keys.rgb, keys.depth):
        rate = by_topic[frames_key].rate_hz
        assert rate is not None and rate > 0.5
    log_times = [t for _topic, t, _pub, _data in iter_messages(path)]
    assert log_times == sorted(log_times) and len(log_times) == info.message_count

    shown = umay("info", str(path))
    assert shown.returncode == 0, shown.stderr
    assert keys.rgb in shown.stdout and "zstd" in shown.stdout and "RgbFrame" in shown.stdout
    assert keys.depth in shown.stdout and "DepthFrame" in shown.stdout


@pytest.mark.xdist_group("recording")  # the module's recording is made once per worker
@pytest.mark.parametrize("service", ["vision", "controller", "actuation"])
def test_replay_check_reproduces_the_recorded_outputs(
    service: str, recording: tuple[Path, str], tmp_path: Path
) -> None:
    path, _ = recording
    proc = replay(path, service, tmp_path, "--check")
    assert proc.returncode == 0, f"stdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    assert "result: OK" in proc.stdout
    assert "differing 0  missing 0  extra 0" in proc.stdout
    assert "matched 0 " not in proc.stdout


@pytest.mark.xdist_group("recording")  # the module's recording is made once per worker
def test_replay_check_fails_on_a_changed_controller_gain_and_names_the_fields(
    recording: tuple[Path, str], tmp_path: Path
) -> None:
    path, _ = recording
    proc = replay(path, "controller", tmp_path, "--check", "--set", "controller.gain=1.5")
    assert proc.returncode == 1, f"stdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    assert "result: FAILED" in proc.stdout
    assert "matched 0  differing" in proc.stdout  # every servoing frame changed
    fields = proc.stdout.split("differing fields", 1)[1]
    assert "linear_m_s[" in fields and "angular_rad_s[" in fields
    assert "header." not in fields  # same frames, same sim times; seq and send time ignored


@pytest.mark.parametrize("service", ["vision", "controller"])
def test_reference_recording_replays_to_the_last_bits(service: str, tmp_path: Path) -> None:
    """The regression check for perception and control: if this fails after an intended
    change, regenerate the reference (tests/data/make_reference.py). The reference may have
    been recorded on another CPU, hence the default tolerances (vision 1e-9, controller 1e-12)
    rather than bit-identity."""
    assert REFERENCE.exists() and REFERENCE.stat().st_size < 2_000_000
    proc = replay(REFERENCE, service, tmp_path, "--check")
    assert proc.returncode == 0, f"stdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    tolerance = {"vision": "1e-09", "controller": "1e-12"}[service]
    assert f"tolerance {tolerance}" in proc.stdout and "result: OK" in proc.stdout


def test_reference_check_catches_a_sub_pixel_change_in_vision(tmp_path: Path) -> None:
    """Vision's 1e-9 still catches a small change: the marker 0.1 mm larger moves the fitted
    corners of the partly hidden target by hundredths of a pixel."""
    proc = replay(REFERENCE, "vision", tmp_path, "--check", "--set", "marker.size_m=0.0601")
    assert proc.returncode == 1, f"stdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    assert "result: FAILED" in proc.stdout
    fields = proc.stdout.split("differing fields", 1)[1].split("first differences", 1)[0]
    assert "target.corners_px[" in fields and "hand." not in fields


def test_umay_record_that_hears_nothing_says_where_it_listened_and_leaves_no_file(
    tmp_path: Path,
) -> None:
    """Nothing runs under the prefix: the exit code and a line on stderr say that nothing was
    heard, and where; no empty recording is left behind, nor the folder made for it, and a
    recording already at the path is left as it was."""
    folder = tmp_path / "new"
    out, endpoint, prefix = folder / "empty.mcap", free_tcp_endpoint(), unique_prefix()
    proc = umay("record", str(out), "--duration", "0.5", "--prefix", prefix, "--connect", endpoint)
    assert proc.returncode == 1, proc.stderr
    assert f"nothing heard on {prefix}/** at {endpoint}, so no file written" in proc.stderr
    assert not out.exists() and not folder.exists()
    kept = tmp_path / "kept.mcap"
    kept.write_bytes(REFERENCE.read_bytes())
    proc = umay("record", str(kept), "--duration", "0.5", "--prefix", prefix, "--connect", endpoint)
    assert proc.returncode == 1, proc.stderr
    assert kept.read_bytes() == REFERENCE.read_bytes()


def test_recorder_writes_concurrent_messages_safely(tmp_path: Path) -> None:
    keys = Keys(unique_prefix())
    session = open_session(connect=[], listen=[free_tcp_endpoint()])
    path = tmp_path / "threads.mcap"
    per_thread, threads = 200, 4
    try:
        with Recorder(path, session, keys, metadata={"prefix": keys.prefix}) as recorder:

            def publish(t: int) -> None:
                for i in range(per_thread):
                    h = Header(seq=i, sim_time_s=0.0, send_time_s=1.0 + i, frame_seq=t)
                    js = JointState(header=h, position_rad=[0.0] * 6, velocity_rad_s=[0.0] * 6)
                    session.put(keys.joint_state, encode(js))
                session.put(f"{keys.prefix}/vision/status", b"not a data key")

            workers = [threading.Thread(target=publish, args=(t,)) for t in range(threads)]
            for w in workers:
                w.start()
            for w in workers:
                w.join()
            for _ in range(50):  # local delivery is asynchronous: let it drain
                if recorder.message_counts().get(keys.joint_state) == per_thread * threads:
                    break
                time.sleep(0.05)
    finally:
        session.close()
    assert recorder.message_counts() == {keys.joint_state: per_thread * threads}
    assert recorder.skipped == threads
    info = read_info(path)
    assert [(c.topic, c.count) for c in info.channels] == [(keys.joint_state, per_thread * threads)]
    per_frame: dict[int, list[int]] = {}
    for _topic, _log, publish_ns, data in iter_messages(path):
        m = decode(data, JointState, FRAME_MAX_BYTES)
        assert publish_ns == round(m.header.send_time_s * 1e9)
        per_frame.setdefault(m.header.frame_seq, []).append(m.header.seq)
    assert {t: sorted(s) for t, s in per_frame.items()} == {
        t: list(range(per_thread)) for t in range(threads)
    }


def test_what_a_recorder_wrote_is_on_disk_while_it_runs(tmp_path: Path) -> None:
    """A recorder killed outright leaves what it has written: the header and metadata with
    the first message (no file before it), then each chunk as it fills, small enough that
    seconds of small messages fill one (at 1 MiB a minute of twists was lost to a kill, and
    the file was empty)."""
    keys = Keys(unique_prefix())
    session = open_session(connect=[], listen=[free_tcp_endpoint()])
    path = tmp_path / "running.mcap"
    try:
        with Recorder(path, session, keys, metadata={"prefix": keys.prefix}) as recorder:
            assert not path.exists()  # nothing heard yet
            for i in range(400):  # about 13 s of joint states at 30 Hz
                h = Header(seq=i, sim_time_s=i / 30, send_time_s=1.0 + i, frame_seq=i)
                js = JointState(header=h, position_rad=[0.1] * 6, velocity_rad_s=[0.0] * 6)
                session.put(keys.joint_state, encode(js))
            for _ in range(50):  # local delivery is asynchronous: let it drain
                if recorder.message_counts().get(keys.joint_state) == 400:
                    break
                time.sleep(0.05)
            running = read_info(path)  # as a kill would leave it: no summary yet
            assert running.damage is not None and running.message_count > 0, running
            assert running.metadata["umay"]["prefix"] == keys.prefix
    finally:
        session.close()
    assert read_info(path).message_count == 400


def test_a_recording_cut_short_is_read_and_replayed_up_to_the_damage(tmp_path: Path) -> None:
    # A recorder killed mid-run leaves no summary, no footer and a last chunk half written.
    full = read_info(REFERENCE)
    cut = tmp_path / "cut.mcap"
    data = REFERENCE.read_bytes()
    cut.write_bytes(data[: len(data) * 6 // 10])
    info = read_info(cut)
    assert info.damage is not None and info.damage.startswith("cut short (no summary)")
    assert 0 < info.message_count < full.message_count
    assert info.metadata == full.metadata  # written first, so kept: a replay needs it
    assert sorted(c.topic for c in info.channels) == sorted(c.topic for c in full.channels)
    log_times = [t for _topic, t, _pub, _data in iter_messages(cut)]
    assert log_times == sorted(log_times) and len(log_times) == info.message_count

    shown = umay("info", str(cut))
    assert shown.returncode == 0, shown.stderr
    said = f"messages     {info.message_count} in 7 channels, chunks not known (no summary)"
    assert said in shown.stdout and info.chunk_count is None
    assert "warning      cut short (no summary)" in shown.stdout

    replayed = umay("replay", str(cut), "--service", "controller", "--check",
                    "--log-dir", str(tmp_path / "logs"))  # fmt: skip
    assert replayed.returncode == 0, replayed.stdout + replayed.stderr
    assert "note: recording cut short (no summary)" in replayed.stdout
    matched = re.search(r"matched (\d+)  differing 0  missing 0  extra 0", replayed.stdout)
    assert matched and int(matched.group(1)) >= 5, replayed.stdout


def copy_recording(src: Path, dst: Path, keep: Callable[[str, int | None], bool]) -> None:
    """``src`` copied to ``dst`` (metadata, schemas, channels), with the messages ``keep``
    accepts by topic and frame number (None: a message without a header)."""
    with src.open("rb") as f, dst.open("wb") as out:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        writer = Writer(out, compression=CompressionType.ZSTD)
        writer.start(profile=reader.get_header().profile, library="test")
        for m in reader.iter_metadata():
            writer.add_metadata(m.name, m.metadata)
        schemas = {i: writer.register_schema(s.name, s.encoding, s.data)
                   for i, s in summary.schemas.items()}  # fmt: skip
        channels = {i: writer.register_channel(c.topic, c.message_encoding, schemas[c.schema_id])
                    for i, c in summary.channels.items()}  # fmt: skip
        for _schema, channel, message in reader.iter_messages():
            if keep(channel.topic, frame_seq_of(message.data)):
                writer.add_message(channels[channel.id], message.log_time, message.data,
                                   message.publish_time, message.sequence)  # fmt: skip
        writer.finish()


def test_replay_check_refuses_a_recording_that_starts_mid_run_and_says_why(
    tmp_path: Path,
) -> None:
    """`umay record` joins a running system: its first frames are missing, and a service
    that keeps state from frame to frame cannot match what it recorded. --check says so
    instead of failing on every frame; a replay without --check still runs."""
    mid_run = tmp_path / "mid_run.mcap"
    copy_recording(REFERENCE, mid_run, lambda _topic, seq: seq is None or seq >= 3)
    checked = replay(mid_run, "vision", tmp_path, "--check")
    assert checked.returncode == 2, checked.stdout + checked.stderr
    assert "--check needs the run from its first frame" in checked.stderr
    assert "starts at frame 3" in checked.stderr
    plain = replay(mid_run, "vision", tmp_path)
    assert plain.returncode == 0, plain.stdout + plain.stderr


def test_replay_refuses_a_recording_without_one_of_the_services_inputs(tmp_path: Path) -> None:
    """A recording made with --keys may lack an input the service needs every frame: replay
    says which at once, instead of waiting for it frame after frame."""
    no_joints = tmp_path / "no_joints.mcap"
    copy_recording(REFERENCE, no_joints, lambda topic, _seq: not topic.endswith("/joint_state"))
    replayed = replay(no_joints, "actuation", tmp_path)
    # Refused before anything starts (it waited 5 s a frame, then exited 0 with no output).
    assert replayed.returncode == 2, replayed.stdout + replayed.stderr
    assert "no sim/joint_state messages: actuation needs" in replayed.stderr


@pytest.mark.xdist_group("recording")  # the module's recording is made once per worker
def test_umay_plot_on_a_real_recording_writes_the_four_figures(
    recording: tuple[Path, str], tmp_path: Path
) -> None:
    path, _ = recording
    proc = umay("plot", str(path), "--out", str(tmp_path / "plots"))
    assert proc.returncode == 0, proc.stderr
    names = sorted(p.name for p in (tmp_path / "plots").glob("*.png"))
    assert names == [
        "ee_velocity.png",
        "feature_error.png",
        "image_trajectory.png",
        "joint_velocities.png",
    ]
    assert all((tmp_path / "plots" / n).stat().st_size > 10_000 for n in names)


def test_a_recording_without_frames_is_small_and_plots(tmp_path: Path) -> None:
    """``--record-without-frames``: every data key but the camera frames, the metadata says
    so, and ``umay plot`` draws its four figures from it."""
    out, prefix = tmp_path / "small.mcap", unique_prefix()
    proc = small_run(prefix, tmp_path / "logs", "--record", str(out), "--record-without-frames")
    assert proc.returncode == 1, proc.stderr  # the short timeout, as in the fixture's run
    keys = Keys(prefix)
    info = read_info(out)
    topics = sorted(c.topic for c in info.channels)
    assert topics == sorted(
        [keys.joint_state, keys.truth, keys.features, keys.twist, keys.joint_command]
    )
    assert info.metadata["umay"]["frames"] == "left out"
    plotted = umay("plot", str(out), "--out", str(tmp_path / "plots"))
    assert plotted.returncode == 0, plotted.stderr
    assert len(list((tmp_path / "plots").glob("*.png"))) == 4


def test_run_plot_keeps_the_recording_it_drew_from_without_camera_frames(tmp_path: Path) -> None:
    """``umay run --plot DIR`` without ``--record``: the four figures, and the recording they
    were drawn from beside them, without the camera frames the figures do not use."""
    plots, prefix = tmp_path / "plots", unique_prefix()
    proc = small_run(prefix, tmp_path / "logs", "--plot", str(plots))
    assert proc.returncode == 1, proc.stderr  # the short timeout, as in the fixture's run
    assert len(list(plots.glob("*.png"))) == 4
    info = read_info(plots / "run.mcap")
    keys = Keys(prefix)
    assert keys.rgb not in {c.topic for c in info.channels} and info.message_count > 0
    assert info.metadata["umay"]["frames"] == "left out"
