"""The benchmark's tables (``docs/bench/*.json``): the goals, the runs, render and loop, the
Kinect model, latency by stage, what distribution adds, services, drops, start-up, workflows.
A run's cells: :mod:`.bench_cells`; the goals and the figures they judge:
:mod:`deploy.bench.goals`; alternations, the hosts and the view have modules of their own."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from deploy.bench.goals import (
    ADDS_GOAL,
    HANDOFF_GOAL,
    LATENCY_P50_GOAL,
    LATENCY_P99_GOAL,
    REAL_TIME_GOAL,
    frame_handoff_ms,
    latency,
)
from deploy.docs.bench_cells import (
    caption,
    code_cell,
    cpu_cell,
    dropped,
    load_cell,
    num,
    run_label,
    runs_note,
    sources_line,
)
from deploy.docs.sources import (
    CPU_WAKEUP_RUN,
    KINECT_LOCKSTEP_RUN,
    KINECT_REALTIME_RUN,
    LOCKSTEP_RUN,
    STARTUP_FRAMES,
    Inputs,
)
from deploy.markdown import link, markdown_table

LATENCY_GOALS = f"{LATENCY_P50_GOAL} / {LATENCY_P99_GOAL} ms"


def bench_headline(inputs: Inputs, here: str) -> str:
    """Issue 26's goals against the runs that measure them."""
    lock = inputs.run(LOCKSTEP_RUN)
    kin = inputs.run(KINECT_LOCKSTEP_RUN)
    rt = inputs.run(KINECT_REALTIME_RUN)
    lk = lock.data
    renderers = lk["render"]["renderers"]
    ref = lk.get("reference_renderer") or {}
    lat, _ = latency(lk)
    rt_dropped = dropped(rt.data, "distributed") or {}
    rt_pipeline = sum(rt_dropped.get(k, 0) for k in ("vision", "controller", "actuation"))
    rss = max(
        (u["peak_rss_mb"] or 0.0)
        for r in (lock, kin, rt)
        for u in r.data["distributed"]["services"].values()
    )
    gl, tiny = renderers.get("gl", {}), renderers.get("tiny", {})
    rows = [
        [
            "render p50, OpenGL (TinyRenderer)",
            f"{num(gl.get('render_ms', {}).get('p50'))} ms "
            f"({num(tiny.get('render_ms', {}).get('p50'))} ms)",
            "≤ 6 ms",
        ],
        [
            "lockstep real-time factor, four-process loop, OpenGL (TinyRenderer)",
            f"{num(lk['distributed']['real_time_factor'])} ({num(ref.get('real_time_factor'))})",
            str(REAL_TIME_GOAL),
        ],
        [
            "same, Kinect model on, depth 320×240",
            num(kin.data["distributed"]["real_time_factor"]),
            "≥ 2",
        ],
        [
            f"realtime, Kinect model on, {rt.data['config']['frames']} frames: frames dropped "
            "by vision, controller, actuation; camera frames the sim skipped; loop rate",
            f"{rt_pipeline}; {rt_dropped.get('camera', 0)}; "
            f"{num(rt.data['distributed']['loop_rate_hz'], '.1f')} frames/s",
            f"0; 0; {rt.data['config']['rgb_hz']:g} frames/s",
        ],
        ["frame publish + transport p50", f"{num(frame_handoff_ms(lk))} ms", f"{HANDOFF_GOAL} ms"],
        [
            f"latency p50 / p99, frame captured → command applied ({lat['n']} frames pooled)",
            f"{num(lat['p50'])} / {num(lat['p99'])} ms",
            LATENCY_GOALS,
        ],
        [
            "what distribution adds (distributed p50 − in-process p50)",
            f"{num(lk['distribution_adds_ms']['p50'])} ms",
            f"{ADDS_GOAL} ms",
        ],
        ["peak RSS, largest service", f"{rss:.0f} MiB", "≤ 300 MB"],
    ]
    sources = [lock, kin, rt]
    awake = inputs.optional_run(CPU_WAKEUP_RUN)
    if awake is not None:  # the same lockstep run with idle CPUs kept awake
        aw = awake.data
        aw_lat, _ = latency(aw)
        rows.append(
            [
                "with idle CPUs kept awake (`supervisor.cpu_wakeup_latency_us = 0`, needs root): "
                "frame publish + transport; latency p50 / p99; what distribution adds",
                f"{num(frame_handoff_ms(aw))} ms; {num(aw_lat['p50'])} / {num(aw_lat['p99'])} ms; "
                f"{num(aw['distribution_adds_ms']['p50'])} ms",
                f"{HANDOFF_GOAL} ms; {LATENCY_GOALS}; {ADDS_GOAL} ms",
            ]
        )
        sources.append(awake)
    if inputs.workflows:  # the user's commands, timed on fresh clones
        rows += workflow_rows([r.data for r in inputs.workflows])
        sources += inputs.workflows
    return (
        markdown_table(["figure (640×480 at 30 Hz)", "measured", "goal"], rows, right_from=1)
        + "\n\n"
        + sources_line(here, sources)
    )


def workflow_rows(reports: Sequence[Mapping[str, Any]]) -> list[list[str]]:
    """The goals' rows of the ``umay bench --workflows`` reports: ``make run`` installed (and
    on a fresh clone), the whole comparison, ``make test`` on a fresh clone; each the range
    over the reports where there are several (a shared host is not as fast from one run to
    the next)."""
    walls: dict[str, list[float]] = {}
    for data in reports:
        for t in data["timings"]:
            walls.setdefault(t["name"], []).append(t["wall_s"])

    def span(name: str, scale: float, unit: str) -> str:
        if name not in walls:
            return "–"
        low, high = min(walls[name]) / scale, max(walls[name]) / scale
        return (
            f"{low:.1f} {unit}" if f"{low:.1f}" == f"{high:.1f}" else f"{low:.1f}–{high:.1f} {unit}"
        )

    return [
        [
            "`make run`, installed (on a fresh clone, the venv and its install included)",
            f"{span('make_run', 1.0, 's')} ({span('make_run_fresh', 1.0, 's')})",
            "≤ 6 s",
        ],
        [
            "`umay compare`, the whole suite, `--jobs 2`",
            span("compare", 1.0, "s"),
            "≤ 90 s (1.5 min)",
        ],
        ["`make test` on a fresh clone", span("make_test_fresh", 60.0, "min"), "≤ 4 min"],
    ]


def bench_workflows(inputs: Inputs, here: str) -> str:
    """Each ``umay bench --workflows`` report: every command it timed, in order."""
    parts = []
    for r in inputs.workflows:
        body = [[f"`{t['command']}`", t["what"], f"{t['wall_s']:.1f}"] for t in r.data["timings"]]
        parts.append(
            caption(here, r.name, r.path, r.data["command"], r.data["machine"])
            + markdown_table(["command", "what", "wall (s)"], body, right_from=2)
        )
    not_run = "*Not run yet: `umay bench --workflows --json docs/bench/workflows/fresh_clone.json`*"
    return "\n\n".join(parts) or not_run


def bench_runs(inputs: Inputs, here: str) -> str:
    """Every run: what it is, its command, its machine, the code it measured."""
    body = []
    for r in inputs.bench:
        m = r.data["machine"]
        body.append(
            [
                f"[`{r.name}`]({link(here, r.path)})",
                run_label(r.data),
                runs_note(r.data),
                f"{m['cpus']} × {cpu_cell(m)}, Python {m['python']}, zenoh {m['zenoh']}; "
                f"load {load_cell(m)}",
                code_cell(m),
            ]
        )
    headers = ["run", "what", "frames", "machine", "code"]
    return markdown_table(headers, body, right_from=5)


def bench_commands(inputs: Inputs, here: str) -> str:
    """The commands that made the runs, as they were typed."""
    lines = [f"{r.data['command']}" for r in (*inputs.bench, *inputs.workflows)]
    return "```sh\n" + "\n".join(lines) + "\numay docs\n```"


def bench_render(inputs: Inputs, here: str) -> str:
    """Render cost per renderer and the loop drawn by each, then the drivers that drew."""
    body: list[list[str]] = []
    drivers: list[str] = []
    for r in inputs.bench:
        d = r.data
        ref = d.get("reference_renderer") or {}
        for name, v in d["render"]["renderers"].items():
            # The scenario's renderer drew the distributed loop; the reference drew its own.
            loop = ref if ref and name == ref.get("renderer") else d["distributed"]
            if v.get("detail") and v["detail"] not in drivers:
                drivers.append(v["detail"])
            body.append(
                [
                    r.name,
                    v["renderer"],
                    num(v["render_ms"]["p50"]),
                    num(v["render_ms"]["p99"]),
                    num(loop.get("loop_rate_hz"), ".1f"),
                    num(loop.get("real_time_factor")),
                ]
            )
    headers = ["run", "renderer", "render p50 (ms)", "p99 (ms)", "loop (frames/s)", "real-time"]
    said = "; ".join(f"`{d}`" for d in drivers)
    return f"{markdown_table(headers, body, right_from=2)}\n\nDrivers: {said}.\n\n" + sources_line(
        here, inputs.bench
    )


def bench_kinect(inputs: Inputs, here: str) -> str:
    """The Kinect sensor model's cost, colour and depth, on perfect images."""
    body = []
    for r in inputs.bench:
        s = r.data["render"]["sensor_model"]
        body.append(
            [
                r.name,
                "×".join(map(str, s["colour_px"])),
                "×".join(map(str, s["depth_px"])),
                num(s["colour_ms"]["p50"]),
                num(s["depth_ms"]["p50"]),
                num(s["total_ms"]["p50"]),
                num(s["total_ms"]["p99"]),
            ]
        )
    headers = ["run", "colour", "depth", "colour p50", "depth p50", "total p50", "total p99"]
    return (
        markdown_table(headers, body, right_from=3)
        + "\n\nTimes in ms. "
        + sources_line(here, inputs.bench)
    )


def bench_latency(inputs: Inputs, here: str) -> str:
    """Frame hand-off, end-to-end latency (pooled over repeated runs), in-process, and what
    distribution adds."""
    body = []
    for r in inputs.bench:
        d = r.data
        lat, over = latency(d)
        body.append(
            [
                r.name,
                runs_note(d),
                num(frame_handoff_ms(d)),
                num(d["distributed"]["latency_ms"]["p50"]),
                num(lat["p50"]),
                num(lat["p99"]),
                num(lat["max"]),
                str(over),
                num(d["inprocess"]["per_frame_ms"]["p50"]),
                num(d["distribution_adds_ms"]["p50"]),
            ]
        )
    headers = [
        "run",
        "frames",
        "frame publish + transport p50",
        "latency p50",
        "all frames: p50",
        "p99",
        "max",
        "over 10 ms",
        "in-process p50",
        "distribution adds",
    ]
    return markdown_table(headers, body) + "\n\nTimes in ms. " + sources_line(here, inputs.bench)


def bench_distribution(inputs: Inputs, here: str) -> str:
    """What distribution adds, and its parts: per stage, distributed p50 less in-process p50
    (transports and the sim's publish count whole)."""
    stages: list[str] = []
    for r in inputs.bench:
        for s in r.data["distribution_adds_ms"]["parts_p50"]:
            if s not in stages:
                stages.append(s)
    body = [
        [
            r.name,
            num(r.data["distribution_adds_ms"]["p50"]),
            *[num(r.data["distribution_adds_ms"]["parts_p50"].get(s)) for s in stages],
        ]
        for r in inputs.bench
    ]
    headers = ["run", "adds p50", *[s.replace("_", " ") for s in stages]]
    return markdown_table(headers, body) + "\n\nTimes in ms. " + sources_line(here, inputs.bench)


def bench_services(inputs: Inputs, here: str) -> str:
    """Peak RSS and CPU per frame, per service."""
    services: list[str] = []
    for r in inputs.bench:
        for s in r.data["distributed"]["services"]:
            if s not in services:
                services.append(s)
    body = []
    for r in inputs.bench:
        u = r.data["distributed"]["services"]
        rss = [num(u.get(s, {}).get("peak_rss_mb"), ".0f") for s in services]
        cpu = [num(u.get(s, {}).get("cpu_ms_per_frame"), ".1f") for s in services]
        body.append([r.name, " / ".join(rss), " / ".join(cpu)])
    order = " / ".join(services)
    headers = ["run", f"peak RSS, MiB: {order}", f"CPU ms per frame: {order}"]
    return markdown_table(headers, body) + "\n\n" + sources_line(here, inputs.bench)


def bench_dropped(inputs: Inputs, here: str) -> str:
    """Frames dropped per stage (the largest count in any run), and camera frames the sim
    skipped (realtime only)."""
    body = []
    for r in inputs.bench:
        dist = dropped(r.data, "distributed") or {}
        syn = dropped(r.data, "synthetic")
        body.append(
            [
                r.name,
                str(dist.get("camera", 0)),
                " / ".join(str(dist.get(k, 0)) for k in ("vision", "controller", "actuation")),
                "–"
                if syn is None
                else " / ".join(str(syn.get(k, 0)) for k in ("vision", "controller", "actuation")),
            ]
        )
    headers = [
        "run",
        "camera frames skipped by the sim",
        "dropped: vision / controller / actuation",
        "synthetic 30 Hz source: the same",
    ]
    return markdown_table(headers, body) + "\n\n" + sources_line(here, inputs.bench)


# The stages of a frame the start-up table shows: each run's latency (with the in-process
# latency of the same frame in brackets) and its two largest parts.
STARTUP_STAGES = (("latency_ms", "latency"), ("frame_transport", "transport"), ("vision", "vision"))
STARTUP_WHAT = "latency (in-process) / transport / vision"


def bench_startup(inputs: Inputs, here: str) -> str:
    """A run's first frames one by one against its later frames (``umay bench --warmup 0``):
    per frame, each run's latency (the in-process functions' on the same frame in brackets),
    frame transport and vision (ms); last, the median of the frames from
    :data:`STARTUP_FRAMES` on."""
    from statistics import median

    parts = []
    for r in inputs.startup:
        runs = [_startup_frames(run) for run in r.data["each_run"]]
        shown = min(STARTUP_FRAMES, *(len(frames) for frames in runs))
        body = [[str(i), *[_startup_cell(frames[i]) for frames in runs]] for i in range(shown)]
        keys = ("inprocess_ms", *(key for key, _ in STARTUP_STAGES))
        later = [
            {key: median(f[key] for f in frames[STARTUP_FRAMES:]) for key in keys}
            for frames in runs
        ]
        body.append([f"median, frames {STARTUP_FRAMES} on", *map(_startup_cell, later)])
        headers = ["frame", *[f"run {i + 1}: {STARTUP_WHAT}" for i in range(len(runs))]]
        parts.append(
            caption(here, r.name, r.path, r.data["command"], r.data["machine"])
            + markdown_table(headers, body, right_from=1)
            + "\n\nTimes in ms."
        )
    return "\n\n".join(parts) or "*No start-up run has been made.*"


def _startup_frames(run: Mapping[str, Any]) -> list[dict[str, float]]:
    """A run's distributed frames in order, each with the in-process latency of its frame."""
    inprocess = {f["frame_seq"]: f["latency_ms"] for f in run["inprocess"]["frames_ms"]}
    return [
        {**f, "inprocess_ms": inprocess[f["frame_seq"]]}
        for f in run["distributed"]["frames_ms"]
        if f["frame_seq"] in inprocess
    ]


def _startup_cell(frame: Mapping[str, float]) -> str:
    latency_ms, transport_ms, vision_ms = (frame[key] for key, _ in STARTUP_STAGES)
    inprocess_ms = frame["inprocess_ms"]
    return f"{num(latency_ms)} ({num(inprocess_ms)}) / {num(transport_ms)} / {num(vision_ms)}"


# --- what distribution adds, stage by stage --------------------------------------------------
def bench_stages(inputs: Inputs, here: str) -> str:
    """The headline run stage by stage: each stage's p50 in the four processes, the same
    function's in one process (none for a hop: one process has no transport), and what
    distribution adds to it; then the codec's share of the hops and vision's cost warm."""
    run = inputs.run(LOCKSTEP_RUN)
    d = run.data
    dist, inproc = d["distributed"]["stages_ms"], d["inprocess"]["stages_ms"]
    parts = d["distribution_adds_ms"]["parts_p50"]
    body = [
        [
            s.replace("_", " "),
            num(dist[s]["p50"]),
            num(inproc[s]["p50"]) if s in inproc else "–",
            num(parts.get(s)),
        ]
        for s in parts
    ]
    body.append(
        [
            "latency, frame captured → command applied",
            num(d["distributed"]["latency_ms"]["p50"]),
            num(d["inprocess"]["per_frame_ms"]["p50"]),
            num(d["distribution_adds_ms"]["p50"]),
        ]
    )
    headers = ["stage", "four processes p50", "one process p50", "distribution adds p50"]
    codec = ", ".join(
        f"{words} {num(inproc[key]['p50'])}"
        for key, words in (
            ("frame_codec", "the frame's (the joint state, the depth image, the colour frame)"),
            ("features_codec", "the features'"),
            ("twist_codec", "the twist's"),
            ("command_codec", "the command's"),
        )
        if key in inproc
    )
    lines = [
        "The messages' codec (built, encoded, decoded), timed apart in one process, p50: "
        f"{codec} ms.",
    ]
    if "vision_warm" in inproc:
        lines.append(
            "In one process, vision called a second time at once on the same frame (its code "
            f"and data warm): p50 {num(inproc['vision_warm']['p50'])} ms, against "
            f"{num(inproc['vision']['p50'])} ms right after the render."
        )
    return (
        markdown_table(headers, body, right_from=1)
        + "\n\n"
        + " ".join(lines)
        + "\n\nTimes in ms, medians of the runs' p50 (they do not add or subtract exactly). "
        + sources_line(here, [run])
    )
