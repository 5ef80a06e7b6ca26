"""One OpenGL context per process, reused world after world (services/sim/renderers.py): a domain
study runs thousands of in-process runs in each worker, and a context made and destroyed per
world leaks native memory."""

from __future__ import annotations

import multiprocessing
import os

import pytest

from common.config import load_scenario
from common.runtime import parse_overrides
from deploy.launch.run_inprocess import run_scenario_inprocess
from services.sim import renderers
from services.sim.world import World

SMALL = ["camera.width_px=160", "camera.height_px=120", "run.timeout_s=0.1", "sim.renderer='gl'"]


def rss_mb() -> float:
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise AssertionError("no VmRSS in /proc/self/status")


def test_thirty_runs_in_one_process_keep_memory_and_descriptors_flat() -> None:
    scenario = load_scenario(None, parse_overrides(SMALL))
    samples = []
    for _ in range(30):
        result = run_scenario_inprocess(scenario)
        assert result.reason == "timeout" and result.frames == 4
        samples.append((rss_mb(), len(os.listdir("/proc/self/fd"))))
    # The first runs fill lasting caches (shaders, framebuffers, imports); after them a new
    # context per world grew the process by megabytes over these 25 runs.
    assert samples[-1][1] == samples[4][1], samples
    assert samples[-1][0] - samples[4][0] < 2.0, samples


def test_a_closed_worlds_context_is_drawn_through_by_the_next_world() -> None:
    scenario = load_scenario(None, parse_overrides(SMALL))
    first = World(scenario)
    if first.renderer != "gl":  # as every OpenGL test: this machine class has EGL
        first.close()
        pytest.fail(f"no OpenGL renderer on this machine: {first.renderer_detail}")
    context = first._gl
    image = first.render_perfect(first.intrinsics)[0]
    second = World(scenario)  # open at once: each its own context
    assert second._gl is not context
    first.close()
    second.close()  # one idle context is kept, the other released
    assert renderers._idle_gl == [context]
    third = World(scenario)
    assert third._gl is context and renderers._idle_gl == []
    # The meshes of the first world were freed and this world's drawn: the same image.
    assert (third.render_perfect(third.intrinsics)[0] == image).all()
    third.close()


def _child_has_no_idle_context(queue: multiprocessing.Queue) -> None:
    queue.put(len(renderers._idle_gl))


def test_a_forked_child_does_not_inherit_the_idle_context() -> None:
    scenario = load_scenario(None, parse_overrides(SMALL))
    World(scenario).close()
    queue: multiprocessing.Queue = multiprocessing.get_context("fork").Queue()
    child = multiprocessing.get_context("fork").Process(
        target=_child_has_no_idle_context, args=(queue,)
    )
    child.start()
    assert renderers._idle_gl  # the parent keeps its own
    assert queue.get(timeout=30) == 0
    child.join(timeout=30)
    assert child.exitcode == 0
