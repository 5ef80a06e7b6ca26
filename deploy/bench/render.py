"""The simulated camera's cost, renderer by renderer, on the same postures (``umay bench``).

For each renderer (the scenario's, and the reference TinyRenderer) a world renders the
colour image and, when its size differs, the depth image, at postures spread along the
scenario's start-to-goal motion; the Kinect sensor model is timed apart on the perfect
images, colour and depth, since it runs after whichever renderer drew them.
"""

from __future__ import annotations

import time

import numpy as np

from common.config import Scenario
from deploy.bench.report import Percentiles, RendererTimes, RenderReport, SensorModelTimes
from services.sim.sensor_model import exposed_rgb, noisy_depth
from services.sim.world import World

REFERENCE_RENDERER = "tiny"


def _summary_ms(values_s: list[float]) -> Percentiles:
    ms = 1000.0 * np.asarray(values_s)
    return Percentiles(
        n=len(ms),
        p50=round(float(np.median(ms)), 4),
        p99=round(float(np.percentile(ms, 99)), 4),
        max=round(float(ms.max()), 4),
    )


def postures(scenario: Scenario, n: int) -> list[np.ndarray]:
    """``n`` joint configurations from the start posture towards the goal (not past it)."""
    from deploy.experiments.accuracy import (
        sample_postures,
    )  # the reachability solver loads on demand

    return sample_postures(scenario, n, np.random.default_rng(0))


def time_renderer(scenario: Scenario, renderer: str, qs: list[np.ndarray]) -> RendererTimes:
    """Perfect colour + depth images (as :meth:`World.render` takes them, model off) at each
    posture of ``qs``, after one warm-up frame."""
    scenario = scenario.model_copy(
        update={"sim": scenario.sim.model_copy(update={"renderer": renderer})}
    )
    world = World(scenario)
    times: list[float] = []
    try:
        for i, q in enumerate([qs[0], *qs]):
            world.reset(q)
            started = time.perf_counter()
            world.render_perfect(world.intrinsics)
            if world.depth_intrinsics != world.intrinsics:
                world.render_perfect(world.depth_intrinsics)
            if i > 0:
                times.append(time.perf_counter() - started)
        return RendererTimes(
            requested=renderer,
            renderer=world.renderer,
            detail=world.renderer_detail,
            render_ms=_summary_ms(times),
        )
    finally:
        world.close()


def time_sensor_model(scenario: Scenario, frames: int) -> SensorModelTimes:
    """The Kinect model (the scenario's settings, switched on) on perfect images of the
    scenario's colour and depth sizes: colour and depth separately and together, each written
    into an array kept between frames, as the sim has it write into a ring slot."""
    world = World(scenario)
    try:
        rgb, _ = world.render_perfect(world.intrinsics)
        _, depth_m = world.render_perfect(world.depth_intrinsics)
    finally:
        world.close()
    model = scenario.camera.kinect.model_copy(update={"enabled": True})
    rng = np.random.default_rng(model.seed)
    rgb_out, depth_out = np.empty_like(rgb), np.empty_like(depth_m)
    colour_s, depth_s = [], []
    for i in range(frames + 1):
        t0 = time.perf_counter()
        exposed_rgb(rgb, model, rng, out=rgb_out)
        t1 = time.perf_counter()
        noisy_depth(depth_m, model, rng, out=depth_out)
        t2 = time.perf_counter()
        if i > 0:
            colour_s.append(t1 - t0)
            depth_s.append(t2 - t1)
    total = [c + d for c, d in zip(colour_s, depth_s, strict=True)]
    return SensorModelTimes(
        colour_px=[world.intrinsics.width_px, world.intrinsics.height_px],
        depth_px=[world.depth_intrinsics.width_px, world.depth_intrinsics.height_px],
        colour_ms=_summary_ms(colour_s),
        depth_ms=_summary_ms(depth_s),
        total_ms=_summary_ms(total),
    )


def run_render_bench(scenario: Scenario, frames: int, reference: bool = True) -> RenderReport:
    """Render cost per renderer (the scenario's; TinyRenderer too when ``reference``) and the
    sensor model's cost, on ``frames`` postures."""
    qs = postures(scenario, frames)
    renderers = [scenario.sim.renderer]
    if reference and REFERENCE_RENDERER not in renderers:
        renderers.append(REFERENCE_RENDERER)
    return RenderReport(
        renderers={name: time_renderer(scenario, name, qs) for name in renderers},
        sensor_model=time_sensor_model(scenario, frames),
    )
