"""The published random-start campaign's starts (docs/campaign/starts.json) as scenarios, for
tests that run one again with a setting on and off."""

from __future__ import annotations

import json
from pathlib import Path

from common.config import Scenario, load_scenario
from common.runtime import parse_overrides
from deploy.experiments.campaign.starts import start_overrides

ROOT = Path(__file__).resolve().parents[2]
BASE = ROOT / "deploy/scenarios/suite/01_baseline.toml"  # the campaign's base scenario


def published_start(name: str) -> dict:
    starts = json.loads((ROOT / "docs/campaign/starts.json").read_text())
    return next(s for s in starts if s["name"] == name)


def start_scenario(name: str, *extra: str) -> Scenario:
    """Start ``name`` as the campaign ran it, with the ``extra`` overrides after its own."""
    start = published_start(name)
    own = start_overrides(
        name, start["q0_rad"], start["target_position_m"], start["target_yaw_rad"]
    )
    return load_scenario(BASE, parse_overrides([*own, *extra]))
