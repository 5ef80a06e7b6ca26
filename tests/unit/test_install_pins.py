"""The install's pins agree with each other (Makefile, pyproject.toml): the uv wheels fetched by
address are of the uv version the Makefile names, one per machine it names, and that uv's own
build backend is the one pyproject.toml asks for. A bump of one without the others would
still install, but slowly: pip reading uv's index page, or uv fetching and running another
uv_build in a build environment instead of building the project itself."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

REPO = Path(__file__).resolve().parents[2]


def makefile_variable(text: str, name: str) -> str:
    found = re.search(rf"^{name} := (.+)$", text, re.MULTILINE)
    assert found, f"the Makefile sets no {name}"
    return found.group(1).strip()


def test_the_pinned_uv_wheels_are_of_the_pinned_version_one_per_machine() -> None:
    text = (REPO / "Makefile").read_text()
    version = makefile_variable(text, "UV_VERSION")
    for machine in ("x86_64", "aarch64"):
        address = makefile_variable(text, f"UV_WHEEL_{machine}")
        wheel = re.fullmatch(
            r"\$\(UV_WHEELS\)/[0-9a-f/]+/uv-(?P<version>[^-]+)-py3-none-(?P<tags>[^/]+)\.whl"
            r"\\#sha256=[0-9a-f]{64}",
            address,
        )
        assert wheel, f"UV_WHEEL_{machine} is not a uv wheel's address with its hash: {address}"
        assert wheel["version"] == version, machine
        assert machine in wheel["tags"] and "manylinux" in wheel["tags"], wheel["tags"]


def test_the_build_backend_is_the_pinned_uvs_own() -> None:
    version = makefile_variable((REPO / "Makefile").read_text(), "UV_VERSION")
    build = tomllib.loads((REPO / "pyproject.toml").read_text())["build-system"]
    assert build["build-backend"] == "uv_build"
    (requirement,) = [Requirement(r) for r in build["requires"]]
    assert canonicalize_name(requirement.name) == "uv-build"
    assert requirement.specifier.contains(version), (str(requirement), version)
