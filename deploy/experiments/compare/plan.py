"""Planning a comparison: every scenario and strategy validated before anything starts."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from common.config import EventAction, Scenario, ScenarioError, load_scenario
from common.runtime import parse_overrides
from deploy.experiments.compare import ALL_MODES, CompareError


# --- planning: validate everything before anything starts ----------------------------------
@dataclass(frozen=True)
class Job:
    """One (scenario, strategy) run; ``overrides`` include the mode."""

    scenario_path: Path
    scenario: Scenario
    mode: str
    overrides: tuple[str, ...]
    record: bool  # the figures scenario's runs are recorded (MCAP) for the figures


@dataclass(frozen=True)
class Plan:
    jobs: tuple[Job, ...]
    modes: tuple[str, ...]
    scenario_names: tuple[str, ...]
    figures_scenario: str


def parse_modes(values: Sequence[str] | None) -> tuple[str, ...]:
    """``--modes`` (space- or comma-separated, ``all`` for every strategy) in the given order,
    duplicates dropped; default: all five."""
    if not values:
        return ALL_MODES
    names = [n.strip() for v in values for n in v.split(",") if n.strip()]
    if not names:
        raise CompareError("--modes: no strategy given")
    if "all" in names:
        return ALL_MODES
    unknown = [n for n in names if n not in ALL_MODES]
    if unknown:
        raise CompareError(
            f"--modes: unknown strategy {unknown[0]!r} (choose from {', '.join(ALL_MODES)}, all)"
        )
    return tuple(dict.fromkeys(names))


def check_jobs(jobs: int) -> int:
    """``--jobs``: how many runs at once, at least one."""
    if jobs < 1:
        raise CompareError(f"--jobs: must be at least 1, not {jobs}")
    return jobs


def scenario_files(directory: Path) -> list[Path]:
    """The ``*.toml`` files of ``directory``, sorted by name (the suite's numbering)."""
    if not directory.exists():
        raise CompareError(f"--scenarios: {directory}: no such directory")
    if not directory.is_dir():
        raise CompareError(f"--scenarios: {directory}: not a directory")
    files = sorted(p for p in directory.glob("*.toml") if p.is_file())
    if not files:
        raise CompareError(f"--scenarios: {directory}: no scenario (*.toml) files in it")
    return files


def job_overrides(overrides: Sequence[str], mode: str) -> tuple[str, ...]:
    """The user's ``--set`` items, then the strategy (so ``--set controller.mode`` cannot
    make two columns run the same strategy)."""
    return (*overrides, f"controller.mode='{mode}'")


def moves_target(scenario: Scenario) -> bool:
    return any(e.action is EventAction.MOVE_TARGET for e in scenario.events)


def plan(
    directory: Path,
    modes: Sequence[str],
    overrides: Sequence[str] = (),
    figures_scenario: str | None = None,
) -> Plan:
    """Every (scenario, mode) job, scenario-major, after validating each scenario with each
    mode (pydantic) and once with the pre-launch check
    (:func:`deploy.launch.reachability.check_scenario`). Raises :class:`CompareError`
    naming the file and the reason."""
    from deploy.launch.reachability import check_scenario as check

    files = scenario_files(directory)
    jobs: list[Job] = []
    names: dict[str, Path] = {}
    for path in files:
        scenario = None
        for mode in modes:
            items = job_overrides(overrides, mode)
            try:
                scenario = load_scenario(path, parse_overrides(list(items)))
            except ScenarioError as exc:
                raise CompareError(str(exc)) from exc
            jobs.append(Job(path, scenario, mode, items, record=False))
        assert scenario is not None
        if scenario.name in names:
            raise CompareError(
                f"{path}: scenario name {scenario.name!r} is also the name of "
                f"{names[scenario.name]} (rows are keyed by name)"
            )
        names[scenario.name] = path
        try:
            check(scenario)
        except ScenarioError as exc:
            raise CompareError(f"{path}: {exc}") from exc
    figures = figures_scenario or next(iter(names))
    if figures not in names:
        stems = {p.stem: n for n, p in names.items()}
        if figures not in stems:
            raise CompareError(
                f"--figures-scenario: no scenario named {figures!r} in {directory} "
                f"(names: {', '.join(names)})"
            )
        figures = stems[figures]
    jobs = [
        Job(j.scenario_path, j.scenario, j.mode, j.overrides, record=j.scenario.name == figures)
        for j in jobs
    ]
    return Plan(tuple(jobs), tuple(modes), tuple(names), figures)
