"""``umay bench --workflows``: commands timed on fresh clones, and the goals' rows from them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from deploy.bench import BenchError
from deploy.bench.workflows import (
    Workflow,
    WorkflowReport,
    clean_environment,
    run_workflows,
)
from deploy.docs.bench_tables import workflow_rows


def a_repository(root: Path) -> Path:
    """A git repository of one commit, to clone."""
    repo = root / "repo"
    repo.mkdir()
    (repo / "README.md").write_text("a checkout\n")
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@example.org"]
    for args in (["init", "--quiet"], ["add", "README.md"], ["commit", "--quiet", "-m", "one"]):
        subprocess.run([*git, *args], cwd=repo, check=True)
    return repo


def python(code: str) -> tuple[str, ...]:
    return (sys.executable, "-c", code)


def test_a_clean_environment_drops_this_checkouts_venv_only() -> None:
    venv = Path("/work/x/.venv")
    env = {"VIRTUAL_ENV": str(venv), "PATH": f"{venv}/bin:/usr/local/bin:/usr/bin", "HOME": "/h"}
    assert clean_environment(env, venv) == {"PATH": "/usr/local/bin:/usr/bin", "HOME": "/h"}


def test_workflows_of_one_clone_share_it_and_another_clone_starts_fresh(tmp_path: Path) -> None:
    repo = a_repository(tmp_path)
    steps = [
        Workflow("write", "a", python("open('left_by_write', 'w').write('x')"), "writes a file"),
        Workflow("read", "a", python("assert open('left_by_write').read() == 'x'"), "reads it"),
        Workflow("fresh", "b", python("import os; assert not os.path.exists('left_by_write')"), ""),
    ]
    said: list[str] = []
    report = run_workflows(tmp_path / "logs", "umay bench --workflows", repo, steps, said.append)
    assert [t.name for t in report.timings] == ["write", "read", "fresh"]
    assert all(t.wall_s > 0.0 for t in report.timings)
    assert report.timings[0].command == " ".join(steps[0].argv)
    assert report.machine.code is not None  # the clone's commit
    assert sorted(p.name for p in (tmp_path / "logs").iterdir()) == [
        "clone.log",
        "fresh.log",
        "read.log",
        "write.log",
    ]
    clones = {Path(line.split(" into ")[1]) for line in said if line.startswith("cloning")}
    assert len(clones) == 2 and not any(c.exists() for c in clones)  # removed afterwards
    # what --json writes reads back the same
    assert WorkflowReport.model_validate(report.model_dump(mode="json")) == report


def test_a_failing_command_is_named_with_its_log_and_its_clone_removed(tmp_path: Path) -> None:
    repo = a_repository(tmp_path)
    steps = [Workflow("broken", "a", python("print('what went wrong'); raise SystemExit(3)"), "")]
    said: list[str] = []
    with pytest.raises(BenchError, match=r"exited 3 after \d+ s; its output: .*broken\.log"):
        run_workflows(tmp_path / "logs", "umay bench --workflows", repo, steps, said.append)
    assert "what went wrong" in (tmp_path / "logs" / "broken.log").read_text()
    clone = next(Path(line.split(" into ")[1]) for line in said if line.startswith("cloning"))
    assert not clone.exists()


def test_the_goals_rows_give_each_command_its_unit_and_the_range_over_runs() -> None:
    def report(*walls: tuple[str, float]) -> dict:
        timings = [{"name": n, "command": n, "what": "", "wall_s": w} for n, w in walls]
        return {"command": "umay bench --workflows", "machine": {}, "timings": timings}

    first = report(("make_run_fresh", 9.04), ("make_run", 2.26), ("compare", 66.0))
    rows = workflow_rows([first])
    assert [r[1] for r in rows] == ["2.3 s (9.0 s)", "66.0 s", "–"]  # make test not timed
    assert [r[2] for r in rows] == ["≤ 6 s", "≤ 90 s (1.5 min)", "≤ 4 min"]
    second = report(("make_run_fresh", 11.4), ("make_run", 2.3), ("compare", 87.1))
    rows = workflow_rows([first, second])
    assert [r[1] for r in rows] == ["2.3 s (9.0–11.4 s)", "66.0–87.1 s", "–"]
