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
