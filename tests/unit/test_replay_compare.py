"""``umay replay --check``'s comparison of a replayed message with the recorded one: which
fields it ignores and how it names the ones that differ."""

from __future__ import annotations

from deploy.recording.replay import compare_messages


def test_compare_ignores_seq_and_send_time_and_names_field_paths() -> None:
    a = {"header": {"seq": 1, "send_time_s": 5.0, "frame_seq": 3}, "v": [1.0, 2.0], "ok": True}
    b = {"header": {"seq": 9, "send_time_s": 6.0, "frame_seq": 3}, "v": [1.0, 2.5], "ok": False}
    numeric, other = compare_messages(a, b)
    assert numeric == {"header.frame_seq": 0.0, "v[0]": 0.0, "v[1]": 0.5}
    assert other == {"ok": ("True", "False")}
