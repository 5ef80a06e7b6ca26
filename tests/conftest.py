"""Shared fixtures: the default scenario and a pybullet world on it."""

from __future__ import annotations

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


def launch_umay_up(log_dir, clock: str, *extra: str):
    """``umay up`` as a child process under a unique prefix: (process, keys, endpoint)."""
    import subprocess
    import sys
    import uuid

    from common.keys import Keys
    from common.transport import free_tcp_endpoint

    endpoint = free_tcp_endpoint()
    keys = Keys(f"test/{uuid.uuid4().hex[:12]}")
    proc = subprocess.Popen(
        [sys.executable, "-m", "deploy", "up", "--clock", clock, "--prefix", keys.prefix,
         "--listen", endpoint, "--connect", endpoint, "--log-dir", str(log_dir), *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    return proc, keys, endpoint
