"""Vision's wait for a colour frame's depth image (services/vision/depth_wait.py): bounded
from the first frame that waited, and a stopped depth stream does not stop vision."""

from __future__ import annotations

from services.vision.depth_wait import DepthWait

PERIOD_S = 1.0 / 30.0


def test_a_frame_whose_depth_image_is_there_is_measured_at_once() -> None:
    wait: DepthWait[str] = DepthWait(0.5)
    assert wait.colour("f3", depth_seq=3, newest_depth_seq=3, now_s=0.0) == "f3"
    assert wait.colour("f4", depth_seq=3, newest_depth_seq=3, now_s=0.0) == "f4"  # 1 Hz depth
    assert (wait.waits, wait.missed) == (0, 0)


def test_a_late_depth_image_releases_the_frame_that_waited_for_it() -> None:
    wait: DepthWait[str] = DepthWait(0.5)
    assert wait.colour("f5", depth_seq=5, newest_depth_seq=4, now_s=0.0) is None
    assert wait.idle(0.1) is None
    assert wait.depth(4) is None  # an older image: still waiting
    assert wait.depth(5) == "f5"
    assert (wait.waits, wait.missed, wait.waiting) == (1, 0, None)


def test_a_stopped_depth_stream_costs_one_wait_then_every_frame_is_measured() -> None:
    """2 s of 30 Hz colour frames after the last depth image: the newer frames replace the
    waiting one without starting its wait again, the wait runs out after 0.5 s, and from then
    on each frame is measured at once with the newest depth image there is."""
    wait: DepthWait[int] = DepthWait(0.5)
    measured = []
    for k in range(60):
        now_s = k * PERIOD_S
        for frame in (wait.colour(k, k, newest_depth_seq=-1, now_s=now_s), wait.idle(now_s)):
            if frame is not None:
                measured.append(frame)
    assert measured[0] == 16  # the frame waiting when 0.5 s had passed since frame 0 began
    assert measured == list(range(16, 60))
    assert (wait.waits, wait.replaced, wait.missed) == (1, 16, 44)  # frames 0-15 dropped
    # Depth again: the next frame that names a newer image waits for it again.
    assert wait.depth(60) is None and not wait.overdue
    assert wait.colour(61, 61, newest_depth_seq=60, now_s=2.1) is None and wait.waits == 2


def test_a_new_run_forgets_the_waiting_frame_and_the_overdue_stream() -> None:
    wait: DepthWait[str] = DepthWait(0.5)
    wait.colour("a", 1, 0, 0.0)
    wait.idle(1.0)
    assert wait.overdue
    wait.colour("b", 2, 0, 1.0)
    wait.forget()
    assert wait.waiting is None and not wait.overdue and wait.missed == 2
    assert wait.colour("c", 1, 0, 2.0) is None  # waits again, as at the start of a run
