"""Figures of a recorded run: a synthetic MCAP recording in, PNGs out."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image as mpimg
import msgpack
import numpy as np
import pytest
from mcap.writer import Writer

from common.camera import CameraIntrinsics
from common.codec import encode
from common.messages import (
    EndEffectorTwist,
    Features,
    Header,
    JointState,
    JointVelocityCommand,
    MarkerFeatures,
    SimTruth,
)
from deploy.recording.channels import METADATA_NAME
from deploy.recording.plots import RunSeries, load_series, plot_recording
from deploy.recording.read import NotARecordingError

PREFIX = "umay/test"
K = CameraIntrinsics.from_fov(640, 480, 57.0)
N_FRAMES = 40
PERIOD_S = 1.0 / 30.0
GAIN = 6.0  # 1/s: the error shrinks as exp(-GAIN t)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
ALL_FIGURES = {
    "image_trajectory.png",
    "ee_velocity.png",
    "feature_error.png",
    "joint_velocities.png",
}


def square(centre: tuple[float, float], side: float, angle_rad: float) -> np.ndarray:
    """4 corners clockwise in the image (v down) from the top-left one."""
    half = side / 2.0
    local = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return local @ np.array([[c, s], [-s, c]]) + np.asarray(centre)


TARGET = square((420.0, 330.0), 44.0, 0.15)
START = square((190.0, 150.0), 60.0, -0.35)


def marker(corners: np.ndarray | None) -> MarkerFeatures:
    if corners is None:
        return MarkerFeatures(
            state="lost",
            corners_px=[[0.0, 0.0]] * 4,
            depth_m=[0.0] * 4,
            depth_sigma_m=[0.0] * 4,
            points_m=[[0.0, 0.0, 0.0]] * 4,
            reason="no blob",
        )
    return MarkerFeatures(
        state="visible",
        corners_px=corners.tolist(),
        depth_m=[0.8] * 4,
        depth_sigma_m=[0.001] * 4,
        # Back-projected at 0.8 m through a 500 px focal length.
        points_m=[[(u - 320.0) * 0.8 / 500.0, (v - 240.0) * 0.8 / 500.0, 0.8] for u, v in corners],
    )


def header(k: int, frame_seq: int | None = None) -> Header:
    return Header(
        seq=k,
        sim_time_s=k * PERIOD_S,
        send_time_s=1.7e9 + k * 0.01,
        frame_seq=k if frame_seq is None else frame_seq,
    )


def fake_run(k: int, gain: float = GAIN) -> dict[str, bytes]:
    """Payloads per key suffix of frame k: the hand's corners approach the target's as
    exp(-GAIN t); the target is hidden by the hand for the last frames."""
    t = k * PERIOD_S
    decay = np.exp(-gain * t)
    hand = TARGET + (START - TARGET) * decay
    hand_seen = k not in (7, 8)  # a short dropout: no dot there
    target_seen = k < N_FRAMES - 8
    error = float(np.sqrt(np.mean((hand - TARGET) ** 2)))
    q_dot = [0.6 * decay * np.cos(j + 0.4 * k * PERIOD_S) for j in range(6)]
    return {
        "sim/rgb": b"not decoded: the big channels are skipped",
        "sim/depth": b"not decoded either",
        "sim/joint_state": encode(
            JointState(
                header=header(k), position_rad=[0.1 * k * PERIOD_S] * 6, velocity_rad_s=q_dot
            )
        ),
        "sim/truth": encode(
            SimTruth(
                header=header(k),
                hand_marker_pose=np.eye(4).ravel().tolist(),
                target_marker_pose=np.eye(4).ravel().tolist(),
                hand_corners_px=hand.tolist(),
                target_corners_px=TARGET.tolist(),
                ee_position_m=[0.3, -0.1 * decay, 0.1],
                joint_position_rad=[0.0] * 6,
            )
        ),
        "vision/features": encode(
            Features(
                header=header(k),
                intrinsics=K,
                hand=marker(hand if hand_seen else None),
                target=marker(TARGET if target_seen else None),
            )
        ),
        "controller/twist": encode(
            EndEffectorTwist(
                header=header(k),
                linear_m_s=[0.12 * decay, -0.05 * decay, 0.08 * decay],
                angular_rad_s=[0.3 * decay, 0.1 * decay, -0.2 * decay],
                valid=hand_seen,
                mode="mpj",
                error_px_rms=error if hand_seen else 0.0,
                converged=hand_seen and error < 0.25,
            )
        ),
        "actuation/joint_command": encode(
            JointVelocityCommand(header=header(k), velocity_rad_s=q_dot)
        ),
    }


def write_recording(
    path: Path,
    skip: tuple[str, ...] = (),
    junk_twist: bool = False,
    runs: int = 1,
    metadata: dict[str, str] | None = None,
    stamp_runs: bool = False,
    run_gains: tuple[float, ...] = (),
) -> Path:
    """``runs`` copies of the run one after the other, as a sim restarted within one
    recording (simulated time back to 0, log time going on; ``stamp_runs``: each copy's
    messages stamped with its own run, 1, 2, ..., as the sim's are; ``run_gains``: each
    copy's own gain, to tell them apart); ``metadata``: the recorder's."""
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="test_plots")
        if metadata is not None:
            writer.add_metadata(METADATA_NAME, metadata)
        schema = writer.register_schema(name="", encoding="", data=b"")
        channels: dict[str, int] = {}
        for n in range(runs * N_FRAMES):
            k = n % N_FRAMES
            payloads = fake_run(k, run_gains[n // N_FRAMES] if run_gains else GAIN)
            if k == N_FRAMES // 2:  # the deadman fired once: must not be plotted
                payloads["actuation/joint_command"] = encode(
                    JointVelocityCommand(
                        header=header(k, frame_seq=-1), velocity_rad_s=[0.0] * 6, reason="deadman"
                    )
                )
            if junk_twist and k == 3:
                payloads["controller/twist"] = b"\xc1 not msgpack"
            for suffix, data in payloads.items():
                if suffix in skip:
                    continue
                if stamp_runs and not suffix.startswith("sim/rgb") and suffix != "sim/depth":
                    fields = msgpack.unpackb(data)
                    fields["header"]["run"] = n // N_FRAMES + 1
                    data = msgpack.packb(fields)
                topic = f"{PREFIX}/{suffix}"
                if topic not in channels:
                    channels[topic] = writer.register_channel(topic, "msgpack", schema)
                ns = int((1.7e9 + n * PERIOD_S) * 1e9)
                writer.add_message(channels[topic], log_time=ns, data=data, publish_time=ns)
        writer.finish()
    return path


def assert_good_png(path: Path) -> None:
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    assert path.stat().st_size > 10_000
    image = mpimg.imread(path)
    assert image.ndim == 3 and image.shape[0] > 400 and image.shape[1] > 800


def test_plot_recording_writes_four_pngs(tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "run.mcap")
    written = plot_recording(rec, tmp_path / "figs")
    assert {p.name for p in written} == ALL_FIGURES
    for p in written:
        assert p.parent == tmp_path / "figs"
        assert_good_png(p)


def test_missing_channel_skips_only_its_figure(tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "run.mcap", skip=("actuation/joint_command",))
    written = plot_recording(rec, tmp_path / "figs")
    assert {p.name for p in written} == ALL_FIGURES - {"joint_velocities.png"}
    assert not (tmp_path / "figs" / "joint_velocities.png").exists()
    for p in written:
        assert_good_png(p)


def test_a_figure_left_out_does_not_leave_another_recordings_in_its_place(
    tmp_path: Path,
) -> None:
    full = write_recording(tmp_path / "full.mcap")
    without = write_recording(tmp_path / "without.mcap", skip=("actuation/joint_command",))
    assert len(plot_recording(full, tmp_path / "figs")) == 4
    plot_recording(without, tmp_path / "figs")
    assert not (tmp_path / "figs" / "joint_velocities.png").exists()


def test_recording_without_wanted_channels_writes_nothing(tmp_path: Path) -> None:
    wanted = tuple(s for s in fake_run(0) if s not in ("sim/rgb", "sim/depth"))
    rec = write_recording(tmp_path / "run.mcap", skip=wanted)
    assert plot_recording(rec, tmp_path / "figs") == []


def test_a_recording_of_two_runs_is_drawn_by_its_last(tmp_path: Path) -> None:
    """A sim restarted mid-recording begins its time again at 0: drawn together, the two
    runs' series would interleave. The last run is drawn, and the series says there were two."""
    first, last = GAIN, 2 * GAIN  # the runs told apart by how fast their error falls
    one = load_series(write_recording(tmp_path / "one.mcap", stamp_runs=True, run_gains=(last,)))
    two = load_series(
        write_recording(tmp_path / "two.mcap", runs=2, stamp_runs=True, run_gains=(first, last))
    )
    assert (one.runs, two.runs) == (1, 2)
    assert two.feat_t_s.shape == two.twist_t_s.shape == (N_FRAMES,)
    np.testing.assert_array_equal(two.error_px_rms, one.error_px_rms)  # the last run's
    assert np.all(np.diff(two.twist_t_s) > 0)


def test_load_series(tmp_path: Path) -> None:
    series = load_series(write_recording(tmp_path / "run.mcap", junk_twist=True))
    assert series.image_size_px == (640, 480)
    assert series.feat_t_s.shape == (N_FRAMES,)
    assert series.hand_px.shape == (N_FRAMES, 4, 2)
    assert int((~series.hand_visible).sum()) == 2
    assert np.isnan(series.hand_px[7]).all()
    np.testing.assert_allclose(series.hand_px[0], START)
    np.testing.assert_allclose(series.target_px[0], TARGET)
    assert not series.target_visible[-1]
    assert series.twist_t_s.shape == (N_FRAMES - 1,)  # one undecodable payload skipped
    assert series.skipped == {"controller/twist": 1}
    assert series.modes == ("mpj",)
    assert series.converged[-1] and not series.converged[0]
    assert series.cmd_rad_s.shape == (N_FRAMES - 1, 6)  # the deadman stop is left out
    assert np.all(np.diff(series.cmd_t_s) > 0)
    assert series.js_position_rad.shape == (N_FRAMES, 6)
    assert series.truth_ee_m.shape == (N_FRAMES, 3)


def test_truncated_recording_keeps_what_precedes_the_damage(tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "run.mcap")
    data = rec.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.8)])  # summary and footer lost
    series = load_series(cut)
    assert series.feat_t_s.size > 0


def test_a_file_that_is_not_mcap_is_refused_by_name(tmp_path: Path) -> None:
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("hostname\n")
    with pytest.raises(NotARecordingError, match=r"notes\.mcap: not an MCAP recording"):
        plot_recording(not_mcap, tmp_path / "figs")
    assert not (tmp_path / "figs").exists()


@pytest.mark.parametrize("threshold", [None, 0.5])
def test_threshold_is_optional(tmp_path: Path, threshold: float | None) -> None:
    rec = write_recording(tmp_path / "run.mcap")
    written = plot_recording(rec, tmp_path / "figs", converged_px=threshold)
    assert "feature_error.png" in {p.name for p in written}


def test_a_target_never_seen_whole_is_drawn_as_fitted() -> None:
    """The hand over the target from the first frame: vision fits the target from its edges
    (partial, fitted) and never sees it whole; the image plot still draws it, and says so."""
    from deploy.recording.plots import _feature_fields, image_trajectory_figure

    fitted = marker(TARGET).model_copy(update={"state": "partial", "fitted": True})
    feats = [
        Features(header=header(k), intrinsics=K, hand=marker(START), target=fitted)
        for k in range(3)
    ]
    fields = _feature_fields(feats)
    assert not fields["target_visible"].any() and fields["target_usable"].all()
    np.testing.assert_allclose(fields["target_px"][0], TARGET)
    series = RunSeries(**fields)
    fig = image_trajectory_figure(series)
    assert fig is not None
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert "target marker (red square, fitted from its edges)" in labels
