"""``umay bench``'s whole benchmark: the distributed run, the in-process baseline on the same
frames, the synthetic 30 Hz source and the renderers' cost, in one report."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from common.config import ClockMode, Scenario
from common.keys import Keys
from deploy.bench.distributed import Observer, run_distributed
from deploy.bench.inprocess import run_inprocess
from deploy.bench.processes import code_version, this_machine
from deploy.bench.render import REFERENCE_RENDERER, run_render_bench
from deploy.bench.report import (
    BenchConfig,
    BenchReport,
    DistributionAdds,
    Ratios,
    ReferenceLoop,
    Velocities,
)
from deploy.bench.stages import INPROCESS_STAGES, LATENCY_STAGES
from deploy.bench.synthetic import MAX_SOURCE_FRAMES, SYNTHETIC_HZ, run_synthetic


def same_commands_max_abs_diff(distributed: Velocities, inprocess: Velocities) -> float | None:
    """The largest difference between the commands of the frames both runs answered (rad/s);
    None when they share none."""
    diffs = [
        float(np.max(np.abs(np.subtract(v, inprocess[k]))))
        for k, v in distributed.items()
        if v is not None and inprocess.get(k) is not None
    ]
    return max(diffs) if diffs else None


def _ratio(a: float | None, b: float | None) -> float | None:
    return round(a / b, 4) if a is not None and b else None


def _minus(a: float | None, b: float | None) -> float | None:
    return round(a - b, 4) if a is not None and b is not None else None


def run_bench(
    scenario_path: str | None,
    scenario: Scenario,
    overrides: list[str],
    frames: int,
    warmup: int,
    log_dir: Path,
    shm: bool = True,
    synthetic_frames: int | None = None,
    command: str = "",
    reference_renderer: bool = True,
    view: bool = False,
    on_phase: Callable[[str], None] = lambda _phase: None,
) -> BenchReport:
    """Distributed run, in-process baseline, synthetic 30 Hz source, and (``reference_renderer``)
    the render cost and the distributed loop again with TinyRenderer. ``on_phase(what)`` as
    each part starts (progress, on a run of minutes)."""
    cam = scenario.camera
    synthetic_frames = frames if synthetic_frames is None else synthetic_frames
    observer: Observer | None = None
    if view:
        from deploy.bench.view import watched_by_a_view

        def observer(keys: Keys, endpoint: str, view_log_dir: Path):  # type: ignore[no-redef]
            return watched_by_a_view(keys, endpoint, view_log_dir, scenario_path, overrides)

    on_phase(f"the four-process loop, {frames} frames after {warmup} to warm up")
    distributed = run_distributed(
        scenario_path, scenario, overrides, frames, warmup, log_dir / "distributed", shm,
        observer=observer,
    )  # fmt: skip
    on_phase("the render and the Kinect model, per renderer")
    render = run_render_bench(scenario, min(frames, 60), reference=reference_renderer)
    reference = None
    if reference_renderer and scenario.sim.renderer != REFERENCE_RENDERER:
        on_phase(f"the four-process loop again, with {REFERENCE_RENDERER}")
        tiny = [*overrides, f"sim.renderer='{REFERENCE_RENDERER}'"]
        loop = run_distributed(
            scenario_path, scenario, tiny, frames, warmup, log_dir / "reference", shm
        )
        reference = ReferenceLoop(
            renderer=REFERENCE_RENDERER,
            render_ms=loop.stages_ms["render"],
            latency_ms=loop.latency_ms,
            loop_rate_hz=loop.loop_rate_hz,
            real_time_factor=loop.real_time_factor,
            dropped=loop.dropped,
        )
    # In lockstep the baseline measures the frames the distributed window measured: a view
    # started before the window lets the sim run on meanwhile, and later frames cost less.
    lockstep = scenario.run.clock is ClockMode.LOCKSTEP
    first = distributed.window[0] if lockstep else warmup
    keep = min(MAX_SOURCE_FRAMES, max(synthetic_frames, 0))
    on_phase("the same steps in one process (the in-process baseline)")
    inprocess, source = run_inprocess(scenario, frames, first, keep)
    synthetic = None
    if synthetic_frames > 0:
        on_phase(f"vision, controller and actuation fed at {SYNTHETIC_HZ:g} Hz")
        synthetic = run_synthetic(
            scenario_path,
            scenario,
            overrides,
            source,
            synthetic_frames,
            SYNTHETIC_HZ,
            log_dir / "synthetic",
            shm,
        )
    # The same frames must have given the same commands (lockstep only: realtime frames
    # are taken at other instants).
    if lockstep:
        inprocess.same_commands_max_abs_diff_rad_s = same_commands_max_abs_diff(
            distributed.velocities, inprocess.velocities
        )
    d50, d99 = distributed.latency_ms.p50, distributed.latency_ms.p99
    i50, i99 = inprocess.per_frame_ms.p50, inprocess.per_frame_ms.p99
    c50 = inprocess.per_frame_with_codec_ms.p50

    # What distribution adds to the in-process loop, and where: per service stage the
    # distributed p50 less the same functions' in-process p50; transports and the sim's
    # publish are all overhead. Medians do not add up exactly: the parts are indicative.
    d_stages, i_stages = distributed.stages_ms, inprocess.stages_ms
    adds_parts = {
        s: _minus(d_stages[s].p50, i_stages[s].p50) if s in INPROCESS_STAGES else d_stages[s].p50
        for s in LATENCY_STAGES
    }

    return BenchReport(
        command=command,
        machine=this_machine(distributed.load_before, code_version()),
        config=BenchConfig(
            width_px=cam.width_px,
            height_px=cam.height_px,
            depth_width_px=cam.depth_intrinsics().width_px,
            depth_height_px=cam.depth_intrinsics().height_px,
            rgb_hz=cam.rgb_hz,
            depth_hz=cam.depth_rate_hz,
            clock=scenario.run.clock.value,
            renderer=render.renderers[scenario.sim.renderer].renderer,
            transport="shm" if shm else "tcp",
            frames=frames,
            warmup=warmup,
            controller_mode=scenario.controller.mode.value,
            view=view,
            overrides=overrides,
        ),
        distributed=distributed,
        inprocess=inprocess,
        distribution_adds_ms=DistributionAdds(p50=_minus(d50, i50), parts_p50=adds_parts),
        render=render,
        reference_renderer=reference,
        ratio=Ratios(
            p50=_ratio(d50, i50), p99=_ratio(d99, i99), vs_with_codec_p50=_ratio(d50, c50)
        ),
        synthetic=synthetic,
    )
