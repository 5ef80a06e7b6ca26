"""``umay replay --check``'s comparison of a replayed message with the recorded one: which
fields it ignores and how it names the ones that differ; lockstep replay's steps."""

from __future__ import annotations

from deploy.recording.replay import JOINT_STATE, SERVICE_IO, Recorded, lockstep_steps
from deploy.recording.replay_check import compare_messages


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
