"""``umay export --foxglove`` of a recording that spans a sim restart: each run exported as it
would be alone (its own fixed scene, calibration and trail), as the live view shows it."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader

from common.config import ScenarioError
from deploy.foxglove import convert, topics
from deploy.foxglove.export import RUN_GAP_S, export_foxglove
from tests.unit.test_plots import write_recording


def exported(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """Per Foxglove topic, (log time, payload) of each message, in the order written."""
    out: dict[str, list[tuple[int, bytes]]] = {}
    with path.open("rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append((message.log_time, message.data))
    return out


def test_a_sim_restart_starts_a_fresh_view_as_live(tmp_path: Path) -> None:
    one = export_foxglove(write_recording(tmp_path / "one.mcap"), tmp_path / "one_fox.mcap")
    two = export_foxglove(write_recording(tmp_path / "two.mcap", runs=2), tmp_path / "two_fox.mcap")
    alone = exported(tmp_path / "one_fox.mcap")
    both = exported(tmp_path / "two_fox.mcap")
    assert alone[topics.CALIBRATION] and alone[topics.SCENE] and alone[topics.ANNOTATIONS]
    # Kept, the first run's view sent the second no calibration nor fixed scene.
    assert {t: len(m) for t, m in both.items()} == {t: 2 * len(m) for t, m in alone.items()}
    # The second run's messages, fixed scene and trail included, are the first run's again,
    # following them on the timeline a second after the first run's last instant.
    end_ns = max(t for messages in alone.values() for t, _ in messages)
    gap_ns = end_ns + round(RUN_GAP_S * 1e9)
    for topic, messages in alone.items():
        times = [t for t, _ in messages]
        assert [t for t, _ in both[topic]] == times + [t + gap_ns for t in times], topic
    assert two.written[topics.CALIBRATION] == 2 * one.written[topics.CALIBRATION]
    assert (one.runs, two.runs) == (1, 2)
    assert any("2 runs" in note for note in two.notes)


def test_an_export_with_nothing_to_show_or_cut_short_leaves_no_file(tmp_path: Path) -> None:
    wanted = ("controller/twist", "vision/features", "sim/joint_state", "sim/rgb", "sim/depth",
              "actuation/joint_command", "sim/truth")  # fmt: skip
    empty = write_recording(tmp_path / "empty.mcap", skip=wanted)
    out = tmp_path / "out.mcap"
    out.write_bytes(b"an earlier export")
    assert not export_foxglove(empty, out).written
    assert out.read_bytes() == b"an earlier export"  # kept: nothing replaced it
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.mcap", "out.mcap"]


def test_stamped_runs_follow_one_another_on_the_timeline(tmp_path: Path) -> None:
    """Runs told apart by Header.run (as the sim stamps them) are shifted alike: in the
    export, every topic's time runs forward across the restart."""
    two = write_recording(tmp_path / "two.mcap", runs=2, stamp_runs=True)
    report = export_foxglove(two, tmp_path / "two_fox.mcap")
    assert report.runs == 2
    for topic, messages in exported(tmp_path / "two_fox.mcap").items():
        times = [t for t, _ in messages]
        assert times == sorted(times), topic


def test_unreadable_overrides_in_a_recordings_metadata_are_refused_by_name(tmp_path: Path) -> None:
    odd = write_recording(tmp_path / "odd.mcap", metadata={"overrides_json": "not json"})
    with pytest.raises(ScenarioError, match="its metadata's overrides_json"):
        export_foxglove(odd, tmp_path / "odd_fox.mcap")
    assert not (tmp_path / "odd_fox.mcap").exists()


def test_an_export_cut_short_leaves_the_earlier_one_and_nothing_half_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An export interrupted partway (Ctrl-C, an error) leaves what was at OUT as it was and
    no partial file beside it."""
    calls = {"n": 0}
    original = convert.ViewState.on_message

    def fails_at_the_tenth(self, suffix, message, jpeg_quality=85):
        calls["n"] += 1
        if calls["n"] == 10:
            raise KeyboardInterrupt
        return original(self, suffix, message, jpeg_quality)

    monkeypatch.setattr(convert.ViewState, "on_message", fails_at_the_tenth)
    out = tmp_path / "out.mcap"
    out.write_bytes(b"an earlier export")
    with pytest.raises(KeyboardInterrupt):
        export_foxglove(write_recording(tmp_path / "run.mcap"), out)
    assert out.read_bytes() == b"an earlier export"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mcap", "run.mcap"]
