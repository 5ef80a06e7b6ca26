"""``umay bench``'s report as the readable table it prints: per stage p50 / p99 / max (ms)
beside the in-process p50, then the summary figures, the services, the renderers, the
synthetic source, and the run against issue 26's goals where they apply."""

from __future__ import annotations

from deploy.bench.goals import against_goals
from deploy.bench.report import LATENCY_GOAL_MS, BenchReport, RenderReport, Summary
from deploy.bench.stages import STAGES


def _f(v: float | int | None, fmt: str = ".2f") -> str:
    return "-" if v is None else format(v, fmt)


def _row(name: str, s: Summary) -> str:
    return f"{name:<20} {_f(s.p50):>8} {_f(s.p99):>8} {_f(s.max):>8}"


def format_render_report(r: RenderReport) -> list[str]:
    """The renderers' lines."""
    lines = [f"{'renderer':<10} {'p50 ms':>8} {'p99 ms':>8}   driver"]
    for name, v in r.renderers.items():
        ms = v.render_ms
        lines.append(f"{name:<10} {ms.p50:>8.2f} {ms.p99:>8.2f}   {v.detail}")
    s = r.sensor_model
    lines.append(
        f"Kinect model ({s.colour_px[0]}x{s.colour_px[1]} colour, "
        f"{s.depth_px[0]}x{s.depth_px[1]} depth): p50 colour {s.colour_ms.p50:.2f} "
        f"+ depth {s.depth_ms.p50:.2f} = {s.total_ms.p50:.2f} ms"
    )
    return lines


def format_report(r: BenchReport) -> str:
    """The readable table: per stage p50 / p99 / max (ms), then the summary figures."""
    c, d, i, m = r.config, r.distributed, r.inprocess, r.machine
    lines = [
        f"umay bench: {c.width_px}x{c.height_px} {c.clock}, renderer {c.renderer}, "
        f"transport {c.transport}, {c.frames} frames after {c.warmup} warm-up; "
        f"load {m.load_start} → {m.load_end} on {m.cpus} CPUs",
        "",
        f"{'stage':<20} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8}   in-process p50 ms",
    ]
    inproc = {s: i.stages_ms[s] for s in ("vision", "controller", "actuation", "apply", "render")}
    for s in STAGES:
        extra = _f(inproc[s].p50) if s in inproc else ""
        lines.append(f"{_row(s, d.stages_ms[s])}   {extra}")
        if s == "frame_transport":
            lines.append(
                f"{_row('  publish+transport', d.frame_handoff_ms)}"
                "   (the frame's hand-off, frame by frame)"
            )
    lines += [
        f"{_row('latency excl. render', d.latency_ms)}   {_f(i.per_frame_ms.p50)}"
        f" (with codec {_f(i.per_frame_with_codec_ms.p50)})",
        f"{'':<20} in-process vision again at once on the same frame (warm): p50 "
        f"{_f(i.stages_ms['vision_warm'].p50)} ms",
    ]
    if d.pooled:  # several runs: the tail over all their frames
        pl = d.pooled.latency_ms
        lines.append(
            f"{_row('latency, all frames', pl)}   ({pl.n} frames of {r.runs} runs; "
            f"{d.pooled.frames_over_goal} over {LATENCY_GOAL_MS:g} ms)"
        )
        lines.append(
            f"{_row('publish+transport', d.pooled.frame_handoff_ms)}   (all frames of the runs)"
        )
    else:
        lines.append(
            f"{'':<20} frames over {LATENCY_GOAL_MS:g} ms: {d.frames_over_goal} of {d.latency_ms.n}"
        )
    adds = r.distribution_adds_ms
    parts = ", ".join(f"{k} {_f(v)}" for k, v in adds.parts_p50.items())
    lines.append(f"distribution adds (p50 distributed - in-process): {_f(adds.p50)} ms")
    lines.append(f"  of which (p50 each, ms): {parts}")
    lines += [
        "",
        f"ratio distributed / in-process (p50): {_f(r.ratio.p50, '.3f')}"
        f"   (p99 {_f(r.ratio.p99, '.3f')}; vs in-process with codec "
        f"{_f(r.ratio.vs_with_codec_p50, '.3f')})",
        f"loop rate {_f(d.loop_rate_hz)} frames/s, real-time factor "
        f"{_f(d.real_time_factor, '.3f')}; colour frames by reference "
        f"{d.frames_by_ref}/{d.frames_received_by_vision}",
        "dropped: " + ", ".join(f"{k} {v}" for k, v in d.dropped.items()),
    ]
    if d.cpu_wakeup_latency is not None:
        lines.append(f"CPU wake-up latency request: {d.cpu_wakeup_latency}")
    if i.same_commands_max_abs_diff_rad_s is not None:
        lines.append(
            "in-process commands vs distributed: max |Δ| "
            f"{i.same_commands_max_abs_diff_rad_s:.3g} rad/s"
        )
    lines += ["", f"{'service':<11} {'CPU s':>7} {'CPU ms/frame':>13} {'peak RSS MiB':>13}"]
    for name, u in d.services.items():
        lines.append(
            f"{name:<11} {_f(u.window_cpu_s, '.2f'):>7} {_f(u.cpu_ms_per_frame, '.1f'):>13}"
            f" {_f(u.peak_rss_mb, '.1f'):>13}"
        )
    if (r.runs or 1) > 1:
        lines[0] += f"; medians of {r.runs} runs"
        lines.append(
            "largest drops in any run: "
            + "; ".join(
                f"{part}: " + ", ".join(f"{k} {v}" for k, v in dropped.items())
                for part, dropped in (r.dropped_max or {}).items()
            )
        )
    lines += ["", *format_render_report(r.render)]
    ref = r.reference_renderer
    if ref:
        lines.append(
            f"loop with {ref.renderer}: render p50 {_f(ref.render_ms.p50)} ms, "
            f"{_f(ref.loop_rate_hz)} frames/s, real-time factor "
            f"{_f(ref.real_time_factor, '.3f')}, latency p50 {_f(ref.latency_ms.p50)} ms"
        )
    s = r.synthetic
    if s:
        lat = s.latency_ms
        lines += [
            "",
            f"synthetic source at {s.rate_hz:.0f} Hz ({s.frames} frames, achieved "
            f"{_f(s.achieved_rate_hz)} Hz): frame published → command published p50 "
            f"{_f(lat.p50)} p99 {_f(lat.p99)} max {_f(lat.max)} ms",
            "  dropped: " + ", ".join(f"{k} {v}" for k, v in s.dropped.items()),
        ]
    lines += ["", *against_goals(r.to_json())]
    return "\n".join(lines)
