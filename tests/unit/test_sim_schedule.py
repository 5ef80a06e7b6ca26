"""The sim's realtime camera ticks: on the frame grid the depth schedule uses, never a
physics step late."""

from __future__ import annotations

from common.config import load_scenario
from services.sim.schedule import DepthSchedule, FrameClock


def run_realtime_ticks(physics_hz: float, rgb_hz: float, frames: int) -> list[tuple[int, bool]]:
    """(physics step, with a depth image) of each frame, the sim's realtime clock stepped one
    physics step at a time, as it is when the sim keeps up."""
    scenario = load_scenario(
        None,
        {"sim": {"physics_hz": physics_hz}, "camera": {"rgb_hz": rgb_hz, "depth_hz": rgb_hz}},
    )
    clock, dt_s = FrameClock.of(scenario), 1.0 / physics_hz
    schedule = DepthSchedule.of(scenario.camera, scenario.frame_period_s)
    t_s, step, out = 0.0, 0, []
    while len(out) < frames:
        missed = clock.missed(t_s)
        if missed is not None:
            assert missed == 0
            with_depth = schedule.due(t_s)
            if with_depth:
                schedule = schedule.taken(t_s, len(out))
            out.append((step, with_depth))
            clock = clock.after_frame(missed)
        t_s += dt_s  # as World.step adds its physics steps
        step += 1
    return out


def test_frames_come_on_their_physics_step_each_with_depth_at_the_colour_rate() -> None:
    for physics_hz, rgb_hz in ((240.0, 30.0), (240.0, 25.0), (240.0, 15.0)):
        ticks = run_realtime_ticks(physics_hz, rgb_hz, 300)
        every = round(physics_hz / rgb_hz)
        assert [step for step, _ in ticks] == [every * k for k in range(300)], (physics_hz, rgb_hz)
        assert all(with_depth for _, with_depth in ticks), (physics_hz, rgb_hz)


def test_the_clock_counts_the_ticks_gone_by_and_keeps_its_grid() -> None:
    clock = FrameClock(1 / 30, next_frame_s=0.1)
    assert clock.missed(0.099) is None
    assert clock.missed(0.1 - 1e-12) == 0  # a float hair short is on time
    assert clock.missed(0.1 + 2.5 / 30) == 2
    assert clock.after_frame(2).next_frame_s == 0.1 + 3 / 30  # the grid, not the late time
