from common.pairing import FramePairer


def test_pairs_by_frame_in_any_order_once_only() -> None:
    p: FramePairer[str, int] = FramePairer(capacity=2)
    assert p.add_a(1, "f1") is None
    assert p.add_b(1, 10) == ("f1", 10)
    assert p.add_b(2, 20) is None
    assert p.add_a(2, "f2") == ("f2", 20)
    assert p.add_a(2, "f2 again") is None and p.add_b(2, 20) is None  # a resent frame
    assert p.add_a(1, "late") is None


def test_capacity_forgets_old_frames() -> None:
    p: FramePairer[str, int] = FramePairer(capacity=2)
    for seq in (5, 6, 7):
        p.add_a(seq, f"f{seq}")
    assert p.add_b(5, 50) is None  # forgotten
    assert p.add_b(7, 70) == ("f7", 70)


def test_a_restarted_source_is_paired_again() -> None:
    p: FramePairer[str, int] = FramePairer(capacity=2)
    for seq in range(10):
        p.add_a(seq, "f")
        p.add_b(seq, seq)
    assert p.add_a(0, "restarted") is None
    assert p.add_b(0, 0) == ("restarted", 0)
