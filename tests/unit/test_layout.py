"""The code's import layers (docs/architecture.md, "Code layout"): common/ needs nothing of
the project, a service needs only common/ and itself, and each folder of deploy/ imports only
the folders below it, so that no arrow runs back up and no two folders need each other.
Lazy imports inside functions count as much as those at the top of a file."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from common.keys import SERVICES

ROOT = Path(__file__).resolve().parents[2]

# deploy/, from the bottom up: a folder (or top-level module) may import its own layer's
# members only when they are itself, and any layer below.
DEPLOY_LAYERS: list[set[str]] = [
    {
        "paths",
        "exit_codes",
        "arguments",
        "interrupts",
        "consoles",
        "cpu_latency",
        "service_process",
        "queries",
        "markdown",
    },
    {"supervisor"},
    {"recording"},
    {"foxglove"},
    {"launch"},
    {"experiments"},
    {"bench"},
    {"docs"},
    {"cli"},
    {"__main__"},
]


def imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports, at any depth of its code."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return found


def part_of(module: str, package: str) -> str | None:
    """The first name under ``package`` of a dotted ``module`` (None: not under it)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == package else None


def sources(folder: str) -> list[Path]:
    return sorted((ROOT / folder).rglob("*.py"))


def test_common_imports_nothing_of_the_services_or_deploy() -> None:
    wrong = {
        (str(p.relative_to(ROOT)), m)
        for p in sources("common")
        for m in imported_modules(p)
        if m.split(".")[0] in ("services", "deploy")
    }
    assert not wrong


@pytest.mark.parametrize("service", SERVICES)
def test_a_service_imports_only_common_and_itself(service: str) -> None:
    wrong = {
        (str(p.relative_to(ROOT)), m)
        for p in sources(f"services/{service}")
        for m in imported_modules(p)
        if m.split(".")[0] == "deploy"
        or (part_of(m, "services") not in (None, service, "__init__") and m != "services")
    }
    assert not wrong


def layer_of(name: str) -> int:
    for i, layer in enumerate(DEPLOY_LAYERS):
        if name in layer:
            return i
    raise AssertionError(f"deploy/{name} has no layer in DEPLOY_LAYERS: add it where it belongs")


def test_deploy_folders_import_only_the_folders_below_them() -> None:
    wrong = []
    for path in sources("deploy"):
        rel = path.relative_to(ROOT / "deploy")
        here = rel.parts[0] if len(rel.parts) > 1 else rel.stem
        if here == "__init__":
            continue
        for module in imported_modules(path):
            there = part_of(module, "deploy")
            if there is None or there == here or there == "__init__":
                continue
            if layer_of(there) >= layer_of(here):
                wrong.append(f"deploy/{rel} imports {module}")
    assert not wrong, "\n".join(wrong)


def test_the_layer_check_sees_a_lazy_import_that_runs_back_up(tmp_path: Path) -> None:
    source = tmp_path / "cli.py"
    source.write_text("def f():\n    from deploy.launch.run import run_once\n")
    assert "deploy.launch.run" in imported_modules(source)
    assert layer_of("recording") < layer_of("launch")
