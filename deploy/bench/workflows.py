"""``umay bench --workflows``: the commands a user waits for, timed on fresh clones.

Issue 26 set goals for what a user sits through, not only for the loop: ``make run`` and
``make test`` on a fresh clone, and ``umay compare`` over the whole suite. Each is timed here
as a user meets it: ``git clone`` of this checkout's commit into a temporary folder, then the
command in the clone, wall clock, its output to a log file of its own. ``make run`` runs twice
(the first makes the venv and installs the packages, the second finds them installed), then
the comparison in the same clone; ``make test`` runs in a second fresh clone, as CI does.
The package caches of the machine (pip's, uv's) stay as they are: a fresh clone, not a fresh
machine. What is not committed is not in the clones, and the report says which commit ran.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel, ConfigDict

from deploy.bench import BenchError
from deploy.bench.processes import REPO_ROOT, code_version, machine_load, this_machine
from deploy.bench.report import Machine

WORKFLOWS_VERSION = 1


@dataclass(frozen=True)
class Workflow:
    """One timed command: its name in the report, the clone it runs in, what it runs there."""

    name: str
    clone: str  # a folder name: workflows of one clone run in order, in the same clone
    argv: tuple[str, ...]
    what: str


WORKFLOWS: tuple[Workflow, ...] = (
    Workflow(
        "make_run_fresh", "run", ("make", "run"), "`make run` on a fresh clone (venv, install)"
    ),
    Workflow("make_run", "run", ("make", "run"), "`make run` again, installed"),
    Workflow(
        "compare",
        "run",
        (".venv/bin/umay", "compare", "--jobs", "2", "--out", "out/compare"),
        "`umay compare --jobs 2`: the whole suite, every strategy, with its figures",
    ),
    Workflow("make_test_fresh", "test", ("make", "test"), "`make test` on a fresh clone"),
)


class WorkflowTiming(BaseModel):
    """A command's wall time (s) in its clone."""

    model_config = ConfigDict(extra="forbid")
    name: str
    command: str
    what: str
    wall_s: float


class WorkflowReport(BaseModel):
    """What ``umay bench --workflows --json`` writes."""

    model_config = ConfigDict(extra="forbid")
    version: int = WORKFLOWS_VERSION
    command: str  # the command that made it, as typed
    machine: Machine
    timings: list[WorkflowTiming]


def clean_environment(env: Mapping[str, str], venv: Path) -> dict[str, str]:
    """``env`` as a new shell on the machine would have it: without this checkout's venv
    (``VIRTUAL_ENV``, its ``bin`` on ``PATH``), so a clone's ``make`` finds the machine's
    Python and makes its own venv, as on a fresh machine."""
    bin_dir = str(venv / "bin")
    out = {k: v for k, v in env.items() if k != "VIRTUAL_ENV"}
    path = [p for p in env.get("PATH", "").split(os.pathsep) if p and p != bin_dir]
    out["PATH"] = os.pathsep.join(path)
    return out


def timed(argv: Sequence[str], cwd: Path, log: Path, env: Mapping[str, str]) -> float:
    """Run ``argv`` in ``cwd`` with its output into ``log``; its wall time (s). BenchError
    naming the command and the log when it fails."""
    log.parent.mkdir(parents=True, exist_ok=True)
    command = " ".join(argv)
    with log.open("w") as out:
        started = time.monotonic()
        try:
            code = subprocess.run(
                list(argv), cwd=cwd, stdout=out, stderr=subprocess.STDOUT, env=dict(env)
            ).returncode
        except OSError as exc:
            raise BenchError(f"`{command}` in {cwd} could not start: {exc}") from exc
        wall_s = time.monotonic() - started
    if code != 0:
        raise BenchError(
            f"`{command}` in {cwd} exited {code} after {wall_s:.0f} s; its output: {log}"
        )
    return wall_s


def run_workflows(
    log_dir: Path,
    command: str,
    repo: Path = REPO_ROOT,
    workflows: Sequence[Workflow] = WORKFLOWS,
    on_step: Callable[[str], None] = lambda what: None,
) -> WorkflowReport:
    """Time ``workflows`` on fresh clones of ``repo``'s commit, in a temporary folder removed
    afterwards; each command's output in ``log_dir/<name>.log``. Raises BenchError."""
    load_start = machine_load()
    env = clean_environment(os.environ, Path(sys.prefix))
    work = Path(tempfile.mkdtemp(prefix="umay-workflows-"))
    timings: list[WorkflowTiming] = []
    code = None
    try:
        cloned: set[str] = set()
        for i, wf in enumerate(workflows):
            clone = work / wf.clone
            if wf.clone not in cloned:
                on_step(f"cloning {repo} into {clone}")
                timed(
                    ("git", "clone", "--quiet", str(repo), str(clone)),
                    work,
                    log_dir / "clone.log",
                    env,
                )
                cloned.add(wf.clone)
                code = code or code_version(clone)
            on_step(f"{i + 1} of {len(workflows)}: {' '.join(wf.argv)} ({wf.name})")
            wall_s = timed(wf.argv, clone, log_dir / f"{wf.name}.log", env)
            timings.append(
                WorkflowTiming(name=wf.name, command=" ".join(wf.argv), what=wf.what, wall_s=wall_s)
            )
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return WorkflowReport(command=command, machine=this_machine(load_start, code), timings=timings)


def format_workflows(report: WorkflowReport) -> str:
    """The timings as a plain-text table."""
    lines = [f"{'workflow':<18}{'wall s':>9}  command"]
    lines += [f"{t.name:<18}{t.wall_s:>9.1f}  {t.command}" for t in report.timings]
    return "\n".join(lines)


def write_workflows(report: WorkflowReport, path: str | Path) -> None:
    Path(path).write_text(report.model_dump_json(indent=2) + "\n")
