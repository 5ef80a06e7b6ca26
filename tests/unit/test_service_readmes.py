"""Each service's README (inputs, outputs, modules) says what its code does: the keys its node
subscribes to with their message types, the keys it publishes, and every module of its folder.
Read from the node's source (no Zenoh session), so a new subscription, publisher or module
without its line in the README fails here."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from common import messages
from common.keys import SERVICES, Keys

ROOT = Path(__file__).resolve().parents[2]
KEYS = Keys("p")
ROW = re.compile(r"^\| `([^`]+)` \| ([^|]+) \|", re.MULTILINE)


def node_io(service: str) -> tuple[set[tuple[str, str]], set[str]]:
    """(key, message type) of each ``subscribe`` and the key of each ``publisher`` call in the
    service's node module, keys relative to the prefix."""
    tree = ast.parse((ROOT / "services" / service / "node.py").read_text())
    inputs, outputs = set(), set()
    for call in ast.walk(tree):
        if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute)):
            continue
        if call.func.attr not in ("subscribe", "publisher") or not call.args:
            continue
        key_arg = call.args[0]
        assert isinstance(key_arg, ast.Attribute), ast.unparse(call)  # keys.<name>
        key = KEYS.relative(getattr(KEYS, key_arg.attr))
        if call.func.attr == "publisher":
            outputs.add(key)
        else:
            inputs.add((key, ast.unparse(call.args[1])))
    return inputs, outputs


def section(text: str, title: str) -> str:
    match = re.search(rf"^## {title}\n(.*?)(?=^## |\Z)", text, re.MULTILINE | re.DOTALL)
    assert match, f"no '## {title}' section"
    return match.group(1)


def rows(text: str) -> list[tuple[str, str]]:
    return [(first, second.strip()) for first, second in ROW.findall(text)]


@pytest.mark.parametrize("service", SERVICES)
def test_readme_lists_the_nodes_inputs_and_outputs(service: str) -> None:
    readme = (ROOT / "services" / service / "README.md").read_text()
    inputs, outputs = node_io(service)
    assert inputs and outputs
    listed_in = {(key, message.strip("`")) for key, message in rows(section(readme, "Inputs"))}
    assert listed_in == inputs
    listed_out = rows(section(readme, "Outputs"))
    assert {key for key, _ in listed_out} == outputs
    for _, message in listed_out:
        assert hasattr(messages, message.strip("`")), message  # a real wire type


@pytest.mark.parametrize("service", SERVICES)
def test_readme_lists_every_module(service: str) -> None:
    folder = ROOT / "services" / service
    readme = (folder / "README.md").read_text()
    listed = {  # a row may name two modules: "`shapes.py`, `scenery.py`"
        name
        for line in section(readme, "Modules").splitlines()
        if line.startswith("| `")
        for name in re.findall(r"`(\w+\.py)`", line.split("|")[1])
    }
    modules = {p.name for p in folder.glob("*.py")} - {"__init__.py", "__main__.py", "node.py"}
    assert listed == modules
    assert "`node.py`" in section(readme, "Modules")  # the shell is named too
