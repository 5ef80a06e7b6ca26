"""A campaign from start to end: check its input, draw its starts (on ``jobs`` processes),
plan every (start, strategy) run as compare does, run them, and write the outputs."""

from __future__ import annotations

import json
import multiprocessing
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from pydantic import ValidationError

from common.config import Scenario, ScenarioError, load_scenario
from common.runtime import parse_overrides
from deploy.experiments.campaign.report import campaign_rows, starts_json, taxonomy_markdown
from deploy.experiments.campaign.starts import (
    DEFAULT_DISTRIBUTION,
    Distribution,
    Start,
    draw_start,
    load_distribution,
)
from deploy.experiments.compare import CompareError
from deploy.experiments.compare.plan import Job, Plan, job_overrides
from deploy.experiments.compare.rows import CompareRow


@dataclass(frozen=True)
class CampaignPlan:
    plan: Plan
    starts: tuple[Start, ...]
    distribution: Distribution
    distribution_path: Path


def _draw_all(
    dist: Distribution,
    base: Scenario,
    indices: Sequence[int],
    jobs: int,
    on_drawn: Callable[[int], None],
) -> Iterator[Start]:
    """The starts of ``indices`` in order, drawn by ``jobs`` processes (inverse kinematics and
    a pybullet scene per draw: the slow part of planning a campaign)."""
    if jobs <= 1 or len(indices) == 1:
        for i in indices:
            yield draw_start(dist, base, i)
            on_drawn(i)
        return
    # Spawned, as compare's and domains' workers are: nothing inherited from this process, nor
    # from the services' forkserver (the default start method from Python 3.14).
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool:
        drawn = pool.map(partial(draw_start, dist, base), indices)
        for i, start in zip(indices, drawn, strict=True):
            yield start
            on_drawn(i)


def parse_only(items: Sequence[str]) -> tuple[int, ...]:
    """The start indices ``--only`` names, in order, each once: a start's name as the
    campaign's reports give it (``start_0003``) or its index (``3``)."""
    indices: list[int] = []
    for item in items:
        digits = item.removeprefix("start_")
        if not digits.isdigit():
            raise CompareError(f"--only: {item!r}: a start's name (e.g. start_0003) or its index")
        indices.append(int(digits))
    return tuple(dict.fromkeys(indices))


def campaign_inputs(
    n: int,
    distribution_path: Path = DEFAULT_DISTRIBUTION,
    seed: int | None = None,
    overrides: Sequence[str] = (),
) -> tuple[Distribution, Path, Scenario]:
    """The distribution (``seed`` instead of its own), its base scenario's path and the base
    scenario with ``overrides``, validated: raises :class:`CompareError` naming the bad
    input. Cheap, so a command checks its input with it before drawing for minutes."""
    if n < 1:
        raise CompareError(f"--n: at least 1 start, not {n}")
    dist, base_path = load_distribution(distribution_path)
    if seed is not None:  # validated as the file's own seed is (model_copy would not)
        try:
            dist = Distribution.model_validate({**dist.model_dump(), "seed": seed})
        except ValidationError as exc:
            raise CompareError(f"--seed {seed}: {exc.errors()[0]['msg']}") from exc
    try:
        base = load_scenario(base_path, parse_overrides(list(overrides)))
    except ScenarioError as exc:
        raise CompareError(str(exc)) from exc
    return dist, base_path, base


def plan_campaign(
    n: int,
    modes: Sequence[str],
    distribution_path: Path = DEFAULT_DISTRIBUTION,
    seed: int | None = None,
    overrides: Sequence[str] = (),
    figures: bool = True,
    jobs: int = 1,
    on_drawn: Callable[[int], None] | None = None,
    only: Sequence[int] = (),
) -> CampaignPlan:
    """Draw ``n`` starts (``seed`` instead of the distribution's), validate every job.
    ``figures``: the first start's runs are recorded, for the figures (False: none is).
    ``jobs``: worker processes drawing at once (each start comes from its own generator, so
    the same starts whatever ``jobs``); ``on_drawn(i)`` after start ``i``, in order.
    ``only``: these starts' indices instead of the first ``n`` (the same starts as in the
    whole campaign: to see some of its runs again)."""
    dist, base_path, base = campaign_inputs(n, distribution_path, seed, overrides)
    indices = tuple(only) or tuple(range(n))
    starts = tuple(_draw_all(dist, base, indices, jobs, on_drawn or (lambda _i: None)))
    jobs: list[Job] = []
    names: list[str] = []
    for start in starts:
        if start.refused:
            continue
        names.append(start.name)
        for mode in modes:
            timeout = () if dist.timeout_s is None else (f"run.timeout_s={dist.timeout_s!r}",)
            items = job_overrides([*start.overrides(), *timeout, *overrides], mode)
            try:
                scenario = load_scenario(base_path, parse_overrides(list(items)))
            except ScenarioError as exc:
                raise CompareError(f"{start.name}: {exc}") from exc
            record = figures and start.name == names[0]
            jobs.append(Job(base_path, scenario, mode, items, record=record))
    figures_start = names[0] if names and figures else ""
    return CampaignPlan(
        Plan(tuple(jobs), tuple(modes), tuple(names), figures_start),
        starts,
        dist,
        distribution_path,
    )


def run_campaign(
    cplan: CampaignPlan,
    n_jobs: int,
    out_dir: Path,
    stop,
    on_start,
    on_done,
    pipeline: str = "distributed",
) -> list[CompareRow]:
    from deploy.experiments.compare.run import run_all

    return run_all(cplan.plan.jobs, n_jobs, out_dir, stop, on_start, on_done, pipeline)


def write_campaign(
    cplan: CampaignPlan, rows: Sequence[CompareRow], out_dir: Path, figures, note: str
) -> list[Path]:
    """compare's outputs, plus campaign.md (the taxonomy), causes.json and starts.json."""
    from deploy.experiments.compare.run import write_outputs

    written = write_outputs(cplan.plan, rows, out_dir, figures, note) if rows else []
    modes = cplan.plan.modes
    md = out_dir / "campaign.md"
    md.write_text(taxonomy_markdown(cplan.starts, rows, modes, cplan.distribution))
    causes = out_dir / "causes.json"
    crows = campaign_rows(cplan.starts, rows, modes)
    causes.write_text(json.dumps([r.model_dump() for r in crows], indent=2) + "\n")
    starts = out_dir / "starts.json"
    starts.write_text(starts_json(cplan.starts))
    return [*written, md, causes, starts]
