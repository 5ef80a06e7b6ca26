"""Shared fixtures: the default scenario and a pybullet world on it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from common.config import Scenario, load_scenario


@pytest.fixture(scope="session")
def scenario() -> Scenario:
    return load_scenario()


@pytest.fixture()
def world(scenario: Scenario):
    from services.sim.world import World

    w = World(scenario)
    yield w
    w.close()


def launch_umay_up(log_dir, clock: str, *extra: str, wrapper: tuple[str, ...] = ()):
    """``umay up`` as a child process under a unique prefix: (process, keys, endpoint).
    ``wrapper``: a command that runs it (it must exec its arguments)."""
    import subprocess
    import sys
    import uuid

    from common.keys import Keys
    from common.session import free_tcp_endpoint

    endpoint = free_tcp_endpoint()
    keys = Keys(f"test/{uuid.uuid4().hex[:12]}")
    proc = subprocess.Popen(
        [*wrapper, sys.executable, "-m", "deploy", "up", "--clock", clock, "--prefix", keys.prefix,
         "--listen", endpoint, "--connect", endpoint, "--log-dir", str(log_dir), *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    return proc, keys, endpoint


def processes_mentioning(text: str) -> list[int]:
    """PIDs of the processes (other than this one) whose command line contains ``text``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if text in cmdline:
            found.append(int(entry.name))
    return found
