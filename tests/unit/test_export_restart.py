"""``umay export --foxglove`` of a recording that spans a sim restart: each run exported as it
would be alone (its own fixed scene, calibration and trail), as the live view shows it."""

from __future__ import annotations

from pathlib import Path

from mcap.reader import make_reader

from deploy.foxglove import topics
from deploy.foxglove.export import export_foxglove
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
    # The second run's messages, fixed scene and trail included, are the first run's again.
    assert both == {topic: messages * 2 for topic, messages in alone.items()}
    assert two.written[topics.CALIBRATION] == 2 * one.written[topics.CALIBRATION]
    assert (one.runs, two.runs) == (1, 2)
    assert any("2 runs" in note for note in two.notes)
