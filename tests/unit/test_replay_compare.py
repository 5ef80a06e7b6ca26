"""``umay replay --check``'s comparison of a replayed message with the recorded one: which
fields it ignores and how it names the ones that differ; lockstep replay's steps."""

from __future__ import annotations

from pathlib import Path

import msgpack
import pytest
from mcap.writer import Writer

from common.codec import encode
from common.messages import EndEffectorTwist, Header
from deploy.recording.read import RecordingReader
from deploy.recording.replay import (
    JOINT_STATE,
    SERVICE_IO,
    Recorded,
    ReplayError,
    frame_going_back,
    lockstep_steps,
    replay_service,
    source_prefix,
)
from deploy.recording.replay_check import (
    ReplayReport,
    check_outputs,
    compare_messages,
    field_defaults,
)
from tests.unit.test_cli import REFERENCE


def test_compare_ignores_seq_and_send_time_and_names_field_paths() -> None:
    a = {"header": {"seq": 1, "send_time_s": 5.0, "frame_seq": 3}, "v": [1.0, 2.0], "ok": True}
    b = {"header": {"seq": 9, "send_time_s": 6.0, "frame_seq": 3}, "v": [1.0, 2.5], "ok": False}
    numeric, other = compare_messages(a, b)
    assert numeric == {"header.frame_seq": 0.0, "v[0]": 0.0, "v[1]": 0.5}
    assert other == {"ok": ("True", "False")}


def test_a_frame_s_joint_state_logged_after_its_trigger_is_still_replayed_with_it() -> None:
    """The recorder logs messages of different services as they reach it: vision's features
    of a frame may come before that frame's joint state. Lockstep replay groups by frame."""
    io = SERVICE_IO["controller"]

    def rec(suffix: str, t: int, seq: int) -> Recorded:
        return Recorded(suffix, t, seq, b"")

    inputs = [
        rec(JOINT_STATE, 1, 0), rec("vision/features", 2, 0),
        rec("vision/features", 3, 1), rec(JOINT_STATE, 4, 1),  # logged late
        rec(JOINT_STATE, 5, 2),  # a frame vision never answered: nothing to replay it with
        rec(JOINT_STATE, 6, 3), rec("vision/features", 7, 3),
    ]  # fmt: skip
    steps = lockstep_steps(inputs, io)
    assert [[(r.suffix, r.frame_seq) for r in step] for step in steps] == [
        [(JOINT_STATE, 0), ("vision/features", 0)],
        [(JOINT_STATE, 1), ("vision/features", 1)],
        [(JOINT_STATE, 3), ("vision/features", 3)],
    ]


def test_the_runs_of_a_recording_that_spans_a_restart_are_replayed_each_with_its_own() -> None:
    """Each run numbers its frames from 0: a frame's joint state is the one of its run, not
    the first run's frame of the same number (which sent the service to the second run early
    and left the rest of the first unanswered)."""
    io = SERVICE_IO["controller"]

    def rec(suffix: str, t: int, seq: int, run: int) -> Recorded:
        return Recorded(suffix, t, seq, b"", run)

    inputs = [
        rec(JOINT_STATE, 1, 0, 7), rec(JOINT_STATE, 2, 1, 7), rec("vision/features", 3, 0, 7),
        rec(JOINT_STATE, 4, 0, 8),  # the restarted sim's frame 0, logged before run 7's 1
        rec("vision/features", 5, 1, 7), rec("vision/features", 6, 0, 8),
    ]  # fmt: skip
    steps = lockstep_steps(inputs, io)
    assert [[(r.run, r.suffix, r.frame_seq) for r in step] for step in steps] == [
        [(7, JOINT_STATE, 0), (7, "vision/features", 0)],
        [(7, JOINT_STATE, 1), (7, "vision/features", 1)],
        [(8, JOINT_STATE, 0), (8, "vision/features", 0)],
    ]


def test_a_field_a_recording_predates_reads_as_its_default() -> None:
    """A twist recorded before ``lifted`` and ``header.run`` existed checks against a replayed
    one that carries them at their defaults; a replayed ``lifted`` of True is a difference."""
    header = Header(seq=0, sim_time_s=0.0, send_time_s=0.0, frame_seq=0)
    twist = EndEffectorTwist(
        header=header, linear_m_s=[0.0] * 3, angular_rad_s=[0.0] * 3, valid=True,
        mode="dynamic", error_px_rms=1.0, converged=False,
    )  # fmt: skip
    old = twist.model_dump()
    del old["lifted"]
    del old["header"]["run"]  # nested: a header recorded before runs were stamped
    defaults = field_defaults(EndEffectorTwist)
    assert defaults["lifted"] is False and "valid" not in defaults  # required: no default
    assert defaults["header"] == {"frame_seq": -1, "recv_time_s": 0.0, "run": 0}
    for replayed, same in ((twist, True), (twist.model_copy(update={"lifted": True}), False)):
        report = ReplayReport(
            recording="r.mcap", service="controller", speed="max", prefix="p", log_path="l",
            inputs_published=2, frames=1, outputs=1, no_answer=0, skipped_inputs=0,
            wall_time_s=0.1, check=True, tolerance=1e-12, ok=True,
        )  # fmt: skip
        check_outputs(report, {0: msgpack.packb(old)}, {0: encode(replayed)}, defaults)
        assert report.ok is same and report.matched == int(same), report
        without = report.model_copy(update={"compared": 0, "matched": 0, "differing": 0})
        check_outputs(without, {0: msgpack.packb(old)}, {0: encode(twist)})
        assert without.other_diffs == {"lifted": 1, "header.run": 1}  # absent vs the default


def test_an_output_a_recording_predates_is_named_and_not_compared() -> None:
    """A twist recorded before the controller published its goal (``goal_px``, default None)
    matches a replayed one that carries a goal: the recording cannot say what it would have
    been, and the report says it was left out. A goal recorded is compared as any field."""
    header = Header(seq=0, sim_time_s=0.0, send_time_s=0.0, frame_seq=0)
    goal = [[10.0, 20.0], [30.0, 20.0], [30.0, 40.0], [10.0, 40.0]]
    twist = EndEffectorTwist(
        header=header, linear_m_s=[0.0] * 3, angular_rad_s=[0.0] * 3, valid=True,
        mode="dynamic", error_px_rms=1.0, converged=False, goal_px=goal,
    )  # fmt: skip
    old = twist.model_dump()
    del old["goal_px"]

    def check(recorded: dict) -> ReplayReport:
        report = ReplayReport(
            recording="r.mcap", service="controller", speed="max", prefix="p", log_path="l",
            inputs_published=2, frames=1, outputs=1, no_answer=0, skipped_inputs=0,
            wall_time_s=0.1, check=True, tolerance=0.0, ok=True,
        )  # fmt: skip
        defaults = field_defaults(EndEffectorTwist)
        check_outputs(report, {0: msgpack.packb(recorded)}, {0: encode(twist)}, defaults)
        return report

    report = check(old)
    assert report.ok and report.matched == 1, report
    assert report.notes == ["not compared, the recording predates them: goal_px"]
    moved = twist.model_dump() | {"goal_px": [[11.0, 20.0], *goal[1:]]}
    assert not check(moved).ok  # a recorded goal is checked


class Topics:
    """A recording as source_prefix sees it: its path and its topics."""

    def __init__(self, *topics: str) -> None:
        self.path = "r.mcap"
        self._topics = list(topics)

    def topics(self) -> list[str]:
        return self._topics


def test_the_prefix_is_the_metadata_s_unless_no_recorded_key_has_it() -> None:
    recorded = Topics("run/a1/sim/rgb", "run/a1/sim/depth", "run/a1/vision/status")
    assert source_prefix(recorded, {"prefix": "run/a1"}) == "run/a1"  # type: ignore[arg-type]
    # `umay record --keys 'run/a1/**'` without --prefix noted the default prefix.
    assert source_prefix(recorded, {"prefix": "umay/umay1"}) == "run/a1"  # type: ignore[arg-type]
    assert source_prefix(recorded, {}) == "run/a1"  # type: ignore[arg-type]


def _report(no_answer: int) -> ReplayReport:
    return ReplayReport(
        recording="r.mcap", service="controller", speed="max", prefix="p", log_path="l",
        inputs_published=4, frames=2, outputs=1, no_answer=no_answer, skipped_inputs=0,
        wall_time_s=0.1, check=True, tolerance=1e-12, ok=True,
    )  # fmt: skip


def test_a_frame_the_service_did_not_answer_fails_the_check() -> None:
    header = Header(seq=0, sim_time_s=0.0, send_time_s=0.0, frame_seq=0)
    twist = EndEffectorTwist(
        header=header, linear_m_s=[0.0] * 3, angular_rad_s=[0.0] * 3, valid=True,
        mode="dynamic", error_px_rms=1.0, converged=False,
    )  # fmt: skip
    for no_answer, ok in ((0, True), (1, False)):
        report = _report(no_answer)
        check_outputs(report, {0: encode(twist)}, {0: encode(twist)})
        assert report.matched == 1 and report.ok is ok


def test_check_refuses_a_recording_of_two_runs_before_starting_anything(tmp_path: Path) -> None:
    """Outputs are matched frame by frame: the second of two runs recorded one after the
    other (or a restarted sim's) would never be compared, and the check said OK."""

    source = RecordingReader(REFERENCE)
    messages = list(source.messages())
    doubled = tmp_path / "two_runs.mcap"
    with doubled.open("wb") as f:
        w = Writer(f)
        w.start(profile="umay", library="test")
        for name, data in source.metadata().items():
            w.add_metadata(name, data)
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        span = messages[-1][2].log_time - messages[0][2].log_time + 1
        for run in range(2):
            for schema, channel, message in messages:
                if schema.id not in schemas:
                    schemas[schema.id] = w.register_schema(
                        schema.name, schema.encoding, schema.data
                    )
                if channel.id not in channels:
                    channels[channel.id] = w.register_channel(
                        channel.topic, channel.message_encoding, schemas[schema.id]
                    )
                t = message.log_time + run * span
                w.add_message(channels[channel.id], t, message.data, t)
        w.finish()
    with pytest.raises(
        ReplayError, match=r"go back \(to frame 0\): the recording holds more than one"
    ):
        replay_service(doubled, "controller", None, True, tmp_path / "logs")
    assert not (tmp_path / "logs").exists()  # refused before anything started


def test_a_resent_frame_is_not_a_second_run() -> None:
    assert frame_going_back([0, 1, 2, 2, 3]) is None  # frame 2 sent again (lockstep resend)
    assert frame_going_back([0, 1, 2, 0, 1]) == 0  # two runs
    assert frame_going_back([]) is None
