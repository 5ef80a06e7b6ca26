"""A convergence-domain study's results: the study file, its tables and its figures.

Pure (from a :class:`Study`, the JSON ``umay domains`` writes): :func:`cell_stats` (success per
rotation × distance cell and the dominant failure cause), :func:`largest_rotation_deg` (per
strategy, the largest rotation handled in at least the goal's share of draws at the study's
fixed distance), :func:`summary_table` and :func:`bands_table` (Markdown, also generated into
README/docs by ``umay docs``). Imperative: :func:`write_heatmaps` (one PNG per strategy).
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from pydantic import BaseModel

from deploy.experiments.campaign.causes import cause_family
from deploy.experiments.compare import ALL_MODES
from deploy.experiments.domains.study import DomainRecord, DomainStart, StudyDefinition
from deploy.markdown import markdown_table

# One letter per failure cause, written in the heat map's cells (docs/domains.md has the key).
CAUSE_LETTERS = {
    "local minimum": "L",
    "collision": "C",
    "marker left the image": "O",
    "joint limit": "J",
    "singularity": "S",
    "timeout": "T",
    "stuck": "K",
    "acquisition failed": "A",
    "error": "E",
}


class Study(BaseModel):
    """What ``umay domains`` writes (``domains.json``): the definition, how it ran, every
    start (refused ones with their reason) and every run."""

    study: StudyDefinition
    study_file: str
    modes: list[str]
    pipeline: str
    executor: str
    wall_time_s: float
    complete: bool  # False: interrupted, the runs that finished
    starts: list[DomainStart]
    runs: list[DomainRecord]


def load_study_json(path: Path) -> Study:
    return Study.model_validate(json.loads(path.read_text()))


def study_modes(study: Study) -> list[str]:
    present = set(study.modes)
    return [m for m in ALL_MODES if m in present] + [m for m in study.modes if m not in ALL_MODES]


def runs_with_starts(study: Study) -> list[tuple[DomainStart, DomainRecord]]:
    starts = {s.name: s for s in study.starts}
    return [(starts[r.start], r) for r in study.runs]


def _rate(ok: int, n: int) -> str:
    return "–" if n == 0 else f"{100.0 * ok / n:.0f}% ({ok}/{n})"


class CellStat(BaseModel):
    rotation_deg: float
    distance_m: float
    runs: int
    converged: int
    refused: int  # starts of the cell refused (each would have run with every strategy)
    causes: dict[str, int]  # failure cause family -> runs

    @property
    def rate(self) -> float | None:
        return None if self.runs == 0 else self.converged / self.runs

    @property
    def dominant(self) -> str:
        """The letter of the commonest failure cause ('' when none failed)."""
        if not self.causes:
            return ""
        cause = max(sorted(self.causes), key=lambda c: self.causes[c])
        return CAUSE_LETTERS.get(cause, "?")


def cell_stats(study: Study, mode: str) -> list[CellStat]:
    """Per rotation × distance (depths pooled), this strategy's runs."""
    out = []
    pairs = runs_with_starts(study)
    for rotation in study.study.rotations_deg:
        for distance in study.study.distances_m:

            def here(s: DomainStart, r: float = rotation, d: float = distance) -> bool:
                return s.rotation_deg == r and s.distance_m == d

            mine = [rec for s, rec in pairs if rec.mode == mode and here(s)]
            causes = Counter(cause_family(r.cause) for r in mine if r.outcome != "converged")
            out.append(
                CellStat(
                    rotation_deg=rotation,
                    distance_m=distance,
                    runs=len(mine),
                    converged=sum(r.outcome == "converged" for r in mine),
                    refused=sum(1 for s in study.starts if here(s) and s.refused),
                    causes=dict(causes),
                )
            )
    return out


def largest_rotation_deg(study: Study, mode: str) -> float | None:
    """The largest rotation up to which, at every rotation of the grid from 0, this strategy
    converged in at least ``success_goal`` of the runs at ``fixed_distance_m`` (depths
    pooled); a rotation without runs (every start refused) ends the range. None: not even 0."""
    goal, fixed = study.study.success_goal, study.study.fixed_distance_m
    best = None
    for c in cell_stats(study, mode):
        if c.distance_m != fixed:
            continue
        if c.rate is None or c.rate < goal:
            break
        best = c.rotation_deg
    return best


def cause_counts(study: Study, mode: str) -> Counter[str]:
    return Counter(cause_family(r.cause) for r in study.runs if r.mode == mode)


def summary_table(study: Study) -> str:
    """Per strategy: runs, success, the largest rotation handled at the fixed distance, and
    every failure cause's count."""
    d = study.study
    causes = [c for c in CAUSE_LETTERS if any(cause_counts(study, m)[c] for m in study.modes)]
    headers = [
        "strategy",
        "runs",
        "converged on goal",
        f"largest rotation ≥ {100 * d.success_goal:.0f}% at {100 * d.fixed_distance_m:g} cm",
        *[f"{c} ({CAUSE_LETTERS[c]})" for c in causes],
    ]
    body = []
    for mode in study_modes(study):
        mine = [r for r in study.runs if r.mode == mode]
        ok = sum(r.outcome == "converged" for r in mine)
        largest = largest_rotation_deg(study, mode)
        counts = cause_counts(study, mode)
        body.append(
            [
                mode,
                str(len(mine)),
                _rate(ok, len(mine)),
                "none" if largest is None else f"{largest:g}°",
                *[str(counts[c]) for c in causes],
            ]
        )
    return markdown_table(headers, body)


def rotation_bands(rotations: Sequence[float]) -> list[tuple[float, float]]:
    """The grid's rotations in bands of 45°: [0, 45], (45, 90], (90, 135], (135, 180]."""
    edges = [(0.0, 45.0), (45.0, 90.0), (90.0, 135.0), (135.0, 180.0)]
    return [(lo, hi) for lo, hi in edges if any(_in_band(r, lo, hi) for r in rotations)]


def _in_band(rotation: float, lo: float, hi: float) -> bool:
    return (lo <= rotation <= hi) if lo == 0.0 else (lo < rotation <= hi)


def bands_table(study: Study) -> str:
    """Success per strategy by displacement band: rotation (45° bands), distance, depth."""
    d = study.study
    bands = rotation_bands(d.rotations_deg)
    columns: list[tuple[str, object]] = [(f"rotation {lo:g}–{hi:g}°", (lo, hi)) for lo, hi in bands]
    columns += [(f"distance {100 * x:g} cm", x) for x in d.distances_m]
    columns += [(f"depth {100 * z:+g} cm", z) for z in d.depths_m]
    pairs = runs_with_starts(study)
    body = []
    for mode in study_modes(study):
        cells = [mode]
        for i, (_, value) in enumerate(columns):
            if i < len(bands):
                lo, hi = value  # type: ignore[misc]
                mine = [r for s, r in pairs if r.mode == mode and _in_band(s.rotation_deg, lo, hi)]
            elif i < len(bands) + len(d.distances_m):
                mine = [r for s, r in pairs if r.mode == mode and s.distance_m == value]
            else:
                mine = [r for s, r in pairs if r.mode == mode and s.depth_m == value]
            cells.append(_rate(sum(r.outcome == "converged" for r in mine), len(mine)))
        body.append(cells)
    return markdown_table(["strategy", *[c for c, _ in columns]], body)


def refusals_table(study: Study) -> str:
    """Starts refused, per reason, and per rotation."""
    reasons = Counter(s.refused for s in study.starts if s.refused)
    body = [[reason, str(n)] for reason, n in reasons.most_common()]
    return markdown_table(["refused at start: reason", "starts"], body)


def refused_by_rotation(study: Study) -> str:
    body = []
    for r in study.study.rotations_deg:
        mine = [s for s in study.starts if s.rotation_deg == r]
        refused = sum(bool(s.refused) for s in mine)
        body.append([f"{r:g}°", str(len(mine)), str(refused), str(len(mine) - refused)])
    return markdown_table(["rotation", "starts drawn", "refused", "run"], body)


def heatmap_path(out_dir: Path, mode: str) -> Path:
    return out_dir / "figures" / f"domain_{mode}.png"


def write_heatmaps(study: Study, out_dir: Path) -> list[Path]:
    """Per strategy, success rate per rotation × distance cell, each cell labelled with its
    converged/runs and the letter of its commonest failure cause (grey: every start refused)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    d = study.study
    written = []
    for mode in study_modes(study):
        stats = cell_stats(study, mode)
        rates = np.full((len(d.distances_m), len(d.rotations_deg)), np.nan)
        fig, ax = plt.subplots(figsize=(1.0 + 0.62 * len(d.rotations_deg), 3.2))
        for c in stats:
            i, j = d.distances_m.index(c.distance_m), d.rotations_deg.index(c.rotation_deg)
            if c.rate is not None:
                rates[i, j] = c.rate
                label = f"{c.converged}/{c.runs}\n{c.dominant}"
            else:
                label = "refused" if c.refused else ""
            ax.text(j, i, label, ha="center", va="center", fontsize=6.5)
        cmap = matplotlib.colormaps["RdYlGn"].with_extremes(bad="0.85")
        image = ax.imshow(np.ma.masked_invalid(rates), cmap=cmap, vmin=0.0, vmax=1.0, aspect="auto")
        ax.set_xticks(range(len(d.rotations_deg)), [f"{r:g}" for r in d.rotations_deg])
        ax.set_yticks(range(len(d.distances_m)), [f"{100 * x:g}" for x in d.distances_m])
        ax.set_xlabel("rotation about the optical axis (°)")
        ax.set_ylabel("distance (cm)")
        key = ", ".join(f"{v} {k}" for k, v in CAUSE_LETTERS.items())
        ax.set_title(f"{mode}: converged on goal per cell (depths pooled)\n{key}", fontsize=8)
        fig.colorbar(image, ax=ax, label="success rate", fraction=0.03)
        fig.tight_layout()
        path = heatmap_path(out_dir, mode)
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def representative_failures(study: Study) -> list[DomainRecord]:
    """Per strategy and failure cause, its first run (start order): the runs to record."""
    seen: set[tuple[str, str]] = set()
    out = []
    for r in study.runs:
        key = (r.mode, cause_family(r.cause))
        if r.outcome != "converged" and key not in seen:
            seen.add(key)
            out.append(r)
    return out


def report_markdown(study: Study, figures: Sequence[str], recordings: dict[str, str]) -> str:
    """report.md beside the study's JSON: the tables, the figures, the failures recorded."""
    d = study.study
    refused = sum(bool(s.refused) for s in study.starts)
    parts = [
        "# Convergence domains",
        "",
        f"{len(study.starts)} starts (up to {d.draws} draws in each of the grid's {d.n_cells} "
        f"cells, seed {d.seed}), "
        f"{refused} refused at start; {len(study.runs)} runs of {len(study.modes)} strategies "
        f"({study.pipeline} pipeline, {study.executor}, {study.wall_time_s / 60:.1f} min"
        + ("" if study.complete else ", **interrupted**: the runs that finished")
        + ").",
        "",
        "## Per strategy",
        "",
        summary_table(study),
        "",
        "## By displacement band",
        "",
        bands_table(study),
        "",
        "## Refused at start",
        "",
        refusals_table(study),
        "",
        refused_by_rotation(study),
        "",
        "## Figures",
        "",
        *[f"![{Path(f).stem}]({f})" for f in figures],
        "",
        "## Representative failures",
        "",
    ]
    failures = representative_failures(study)
    parts += [
        f"- {r.key}: **{r.cause}**; {r.result.detail}"
        + (f" ([recording]({recordings[r.key]}))" if r.key in recordings else "")
        for r in failures
    ] or ["None."]
    return "\n".join(parts) + "\n"


def verdict_markdown(study: Study) -> str:
    """What the evidence favours, and where, as sentences built from the study's numbers: per
    strategy its success and largest rotation at the fixed distance and its commonest failure
    cause; per rotation band the strategy with the highest success (ties named together; a band
    every strategy ties on, or none reaches the goal in, said so)."""
    d = study.study
    lines = []
    for mode in study_modes(study):
        mine = [r for r in study.runs if r.mode == mode]
        ok = sum(r.outcome == "converged" for r in mine)
        largest = largest_rotation_deg(study, mode)
        failures = Counter(cause_family(r.cause) for r in mine if r.outcome != "converged")
        worst = ", ".join(f"{c} ({n})" for c, n in failures.most_common(2)) or "none"
        reach = "no rotation" if largest is None else f"up to {largest:g}°"
        if largest == 0:
            reach = "unturned starts only"
        lines.append(
            f"- **{mode}**: {_rate(ok, len(mine))} on goal; in ≥ {100 * d.success_goal:.0f}% of "
            f"draws at {100 * d.fixed_distance_m:g} cm: {reach}; commonest failures: {worst}."
        )
    pairs = runs_with_starts(study)
    for lo, hi in rotation_bands(d.rotations_deg):
        rates = {}
        for mode in study_modes(study):
            mine = [r for s, r in pairs if r.mode == mode and _in_band(s.rotation_deg, lo, hi)]
            if mine:
                rates[mode] = sum(r.outcome == "converged" for r in mine) / len(mine)
        if not rates:
            lines.append(f"- Rotations {lo:g}–{hi:g}°: no start could be run.")
            continue
        best = max(rates.values())
        leaders = [m for m, v in rates.items() if round(v, 3) == round(best, 3)]
        if best == 0:
            said = "no strategy reached the goal"
        elif len(leaders) == len(rates) > 1:
            said = f"all {len(rates)} tie ({100 * best:.0f}% on goal)"
        else:
            said = f"best {', '.join(leaders)} ({100 * best:.0f}% on goal)"
        lines.append(f"- Rotations {lo:g}–{hi:g}°: {said}.")
    return "\n".join(lines)
