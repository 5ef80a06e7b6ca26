"""``umay replay --check``'s comparison of a replayed message with the recorded one: which
fields it ignores and how it names the ones that differ; lockstep replay's steps."""

from __future__ import annotations

import msgpack

from common.codec import encode
from common.messages import EndEffectorTwist, Header
from deploy.recording.replay import (
    JOINT_STATE,
    SERVICE_IO,
    Recorded,
    lockstep_steps,
    source_prefix,
)
from deploy.recording.replay_check import (
    ReplayReport,
    check_outputs,
    compare_messages,
    field_defaults,
)


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
