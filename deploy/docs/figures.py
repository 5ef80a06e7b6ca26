"""The docs' figures drawn from the JSON they come from, as the tables are: rewritten by
``umay docs`` (not by ``--check``: a PNG's bytes depend on the matplotlib that drew it, so a
figure is compared with its JSON by drawing it, not by reading it)."""

from __future__ import annotations

from pathlib import Path

from deploy.docs.sources import LOCKSTEP_RUN, Inputs

# The per-frame stages of the lockstep benchmark's first run (docs/performance.md).
BENCH_STAGES_PNG = "docs/figures/bench_stages.png"


def redraw(root: Path, inputs: Inputs) -> list[str]:
    """Draw every figure whose JSON is there; write those whose bytes changed. Returns the
    figures rewritten (paths relative to ``root``)."""
    from deploy.bench.figure import bench_png  # matplotlib: only when drawing

    lockstep = next((r for r in inputs.bench if r.name == LOCKSTEP_RUN), None)
    runs = lockstep.data.get("each_run") if lockstep else None
    png = bench_png(runs[0]) if runs else None
    path = root / BENCH_STAGES_PNG
    if png is None or (path.is_file() and path.read_bytes() == png):
        return []
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png)
    return [BENCH_STAGES_PNG]
