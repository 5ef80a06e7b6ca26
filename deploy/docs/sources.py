"""What the generated tables come from: the comparison's rows, the benchmark runs, the domain
study; loaded once per ``umay docs``."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from deploy.experiments.compare.rows import CompareRow, rows_from_json

REPO_ROOT = Path(__file__).resolve().parents[2]
RESULTS_JSON = "docs/results/results.json"
BENCH_DIR = "docs/bench"
# umay bench --alternate: one change judged by pairs of runs without and with it.
ALTERNATIONS_DIR = "docs/bench/alternations"
# umay bench --warmup 0: every frame of each run from the first, for a run's start-up.
STARTUP_DIR = "docs/bench/startup"
# The headline lockstep run's command on other hosts of the machine class, one JSON each.
HOSTS_DIR = "docs/bench/hosts"
# umay bench --workflows: make run, umay compare and make test timed on fresh clones.
WORKFLOWS_DIR = "docs/bench/workflows"
# umay bench --view: the loop with a live view and a Foxglove client, in pairs of runs without
# and with it (``without<suffix>.json``, then ``with<suffix>.json``).
VIEW_DIR = "docs/bench/view"
# Frames shown one by one from a run's start; the rest are summed up by their median.
STARTUP_FRAMES = 10
DOMAINS_JSON = "docs/domains/domains.json"  # the published convergence-domain study
ACCURACY_JSON = "docs/vision/accuracy.json"  # umay accuracy on the suite's target placements
CAMPAIGN_DIR = "docs/campaign"
CAMPAIGN_JSON = f"{CAMPAIGN_DIR}/causes.json"  # the random-start campaign: one cause per run
CAMPAIGN_STARTS_JSON = f"{CAMPAIGN_DIR}/starts.json"  # its starts, as drawn
CAMPAIGN_RESULTS_JSON = f"{CAMPAIGN_DIR}/results.json"  # its runs' results, as compare's rows
# The same starts again with one of constant's settings changed (``umay campaign --modes
# constant --set ... --out docs/campaign/<folder>``, the command in docs/campaign.md): each
# folder's runs are one more row of the campaign's taxonomy, under this label, and of the
# README's summary where marked (the ablations of the controller's own parts are not).
CONSTANT_VARIANTS = (
    ("constant_per_corner", "constant, per_corner depths", True),  # constant_depth = per_corner
    ("constant_lift", "constant, clearance lifting", False),  # clearance_correction = lift
    ("constant_hand_held", "constant, hidden hand held", False),  # predict_hand_s = 0
)
# The forearm's bound under a camera calibration error: the campaign's first starts, dynamic,
# the camera's position believed 5 mm off along each axis, with the bound on and off (``umay
# campaign --n 60 --modes dynamic --set camera.calibration_error.position_m=<offset> --set
# controller.keep_forearm_off_object=<on> --out docs/campaign/calibration/<folder>_forearm_<on>``).
CALIBRATION_DIR = f"{CAMPAIGN_DIR}/calibration"
CALIBRATION_OFFSETS = (  # folder, the offset (m, base frame) as the command gives it
    ("x_plus", "[0.005,0,0]"),
    ("x_minus", "[-0.005,0,0]"),
    ("y_plus", "[0,0.005,0]"),
    ("y_minus", "[0,-0.005,0]"),
)
# The suite at its own camera (480×360 at 15 Hz) and at the default's (640×480 at 30 Hz), both
# in-process: what moving the suite to the default's camera would change (docs/scenarios.md).
SUITE_CAMERA_DIR = "docs/results/suite_camera"
SUITE_CAMERAS = ("480x360_15hz", "640x480_30hz")
# The same small study through each executor (one folder each, ``umay domains --out``).
EXECUTORS_DIR = "docs/domains/executors"

# The benchmark runs the headline figures come from (docs/bench/<name>.json).
LOCKSTEP_RUN = "lockstep_640x480"
KINECT_LOCKSTEP_RUN = "lockstep_640x480_kinect_depth320x240"
KINECT_REALTIME_RUN = "realtime_640x480_kinect"
# The lockstep run again with idle CPUs kept awake (supervisor.cpu_wakeup_latency_us = 0).
CPU_WAKEUP_RUN = "lockstep_640x480_cpu_wakeup0"


class DocsError(ValueError):
    """A document whose markers are malformed, or a source that cannot be read."""


# --- inputs ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class BenchRun:
    """One ``umay bench --json`` file: its name (the file's stem), its content and its folder."""

    name: str
    data: Mapping[str, Any]
    folder: str = BENCH_DIR

    @property
    def path(self) -> str:
        return f"{self.folder}/{self.name}.json"


@dataclass(frozen=True)
class CampaignVariant:
    """The campaign's starts run again with one of constant's settings changed."""

    folder: str  # under CAMPAIGN_DIR
    label: str  # its row's name
    runs: Sequence[Mapping[str, Any]]
    in_summary: bool = True  # a row of the README's summary too

    @property
    def path(self) -> str:
        return f"{CAMPAIGN_DIR}/{self.folder}/causes.json"


@dataclass(frozen=True)
class CalibrationRun:
    """One campaign of the calibration study: its offset, the forearm's bound on or off, its
    runs' causes and results."""

    folder: str  # under CALIBRATION_DIR
    offset: str  # camera.calibration_error.position_m, as the command gives it
    forearm_kept_off: bool
    causes: Sequence[Mapping[str, Any]]
    results: Sequence[CompareRow]

    @property
    def path(self) -> str:
        return f"{CALIBRATION_DIR}/{self.folder}/results.json"


def _calibration_runs(root: Path) -> list[CalibrationRun]:
    """The calibration study's campaigns that have been run, in the study's order."""
    runs = []
    for name, offset in CALIBRATION_OFFSETS:
        for kept in (True, False):
            folder = f"{name}_forearm_{str(kept).lower()}"
            results = _records(root / CALIBRATION_DIR / folder / "results.json")
            if results:
                causes = _records(root / CALIBRATION_DIR / folder / "causes.json")
                rows = [CompareRow.model_validate(r) for r in results]
                runs.append(CalibrationRun(folder, offset, kept, causes, rows))
    return runs


@dataclass(frozen=True)
class Inputs:
    results: Sequence[CompareRow] = ()
    bench: Sequence[BenchRun] = ()  # sorted by name
    alternations: Sequence[tuple[str, Any]] = ()  # (file stem, AlternationReport), by name
    startup: Sequence[BenchRun] = ()  # runs without warm-up frames (STARTUP_DIR), by name
    hosts: Sequence[BenchRun] = ()  # the headline lockstep run on other hosts (HOSTS_DIR)
    workflows: Sequence[BenchRun] = ()  # the user's commands timed (WORKFLOWS_DIR), by name
    view: Sequence[BenchRun] = ()  # the loop without and with a live view (VIEW_DIR), by name
    domains: Any = None  # the domain study (deploy.experiments.domains.report.Study), if run
    executors: Sequence[tuple[str, Any]] = ()  # (folder, Study) of the executor comparison
    campaign: Sequence[Mapping[str, Any]] = ()  # the campaign's runs, each with its cause
    campaign_starts: Sequence[Mapping[str, Any]] = ()  # its starts (CAMPAIGN_STARTS_JSON)
    campaign_results: Sequence[CompareRow] = ()  # its runs' results (CAMPAIGN_RESULTS_JSON)
    variants: Sequence[CampaignVariant] = ()  # constant's variants run (CONSTANT_VARIANTS)
    calibration: Sequence[CalibrationRun] = ()  # the calibration study (CALIBRATION_OFFSETS)
    accuracy: Sequence[Mapping[str, Any]] = ()  # vision's accuracy, one record per condition
    # The suite's rows per camera (SUITE_CAMERAS), where both have been run.
    suite_cameras: Sequence[tuple[str, Sequence[CompareRow]]] = ()

    def run(self, name: str) -> BenchRun:
        found = self.optional_run(name)
        if found is None:
            raise DocsError(
                f"{BENCH_DIR}/{name}.json is missing (run the command in performance.md)"
            )
        return found

    def optional_run(self, name: str) -> BenchRun | None:
        return next((r for r in self.bench if r.name == name), None)


def _bench_runs(root: Path, folder: str) -> list[BenchRun]:
    """Every ``umay bench --json`` file of ``folder`` (under ``root``), by name."""
    return [
        BenchRun(p.stem, json.loads(p.read_text()), folder)
        for p in sorted((root / folder).glob("*.json"))
    ]


def _records(path: Path) -> list[Mapping[str, Any]]:
    """A JSON list of records, or none where it has not been made yet."""
    return json.loads(path.read_text()) if path.is_file() else []


def load_inputs(root: Path) -> Inputs:
    """The comparison's rows and every benchmark run under ``root``."""
    try:
        results = rows_from_json((root / RESULTS_JSON).read_text())
        bench = _bench_runs(root, BENCH_DIR)
        from deploy.bench.alternate import load_alternation
        from deploy.experiments.domains.report import load_study_json

        alternations = [
            (p.stem, load_alternation(json.loads(p.read_text())))
            for p in sorted((root / ALTERNATIONS_DIR).glob("*.json"))
        ]
        startup = _bench_runs(root, STARTUP_DIR)
        hosts = _bench_runs(root, HOSTS_DIR)
        workflows = _bench_runs(root, WORKFLOWS_DIR)
        view = _bench_runs(root, VIEW_DIR)
        domains = None
        if (root / DOMAINS_JSON).is_file():
            domains = load_study_json(root / DOMAINS_JSON)
        executors = [
            (path.parent.name, load_study_json(path))
            for path in sorted((root / EXECUTORS_DIR).glob("*/domains.json"))
        ]
        campaign = _records(root / CAMPAIGN_JSON)
        campaign_starts = _records(root / CAMPAIGN_STARTS_JSON)
        campaign_results = [
            CompareRow.model_validate(r) for r in _records(root / CAMPAIGN_RESULTS_JSON)
        ]
        variants = [
            CampaignVariant(folder, label, runs, in_summary)
            for folder, label, in_summary in CONSTANT_VARIANTS
            if (runs := _records(root / CAMPAIGN_DIR / folder / "causes.json"))
        ]
        calibration = _calibration_runs(root)
        accuracy = _records(root / ACCURACY_JSON)
        cameras = [(n, root / SUITE_CAMERA_DIR / n / "results.json") for n in SUITE_CAMERAS]
        suite_cameras = [
            (name, rows_from_json(path.read_text())) for name, path in cameras if path.is_file()
        ]
    except (OSError, ValueError) as exc:
        raise DocsError(f"cannot read the sources: {exc}") from exc
    return Inputs(
        results=results,
        bench=bench,
        alternations=alternations,
        startup=startup,
        hosts=hosts,
        workflows=workflows,
        view=view,
        domains=domains,
        executors=executors,
        campaign=campaign,
        campaign_starts=campaign_starts,
        campaign_results=campaign_results,
        variants=variants,
        calibration=calibration,
        accuracy=accuracy,
        suite_cameras=suite_cameras if len(suite_cameras) == len(SUITE_CAMERAS) else (),
    )
