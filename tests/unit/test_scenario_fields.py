"""docs/scenarios.md's field reference, generated from the models that validate a scenario."""

from __future__ import annotations

from common.config import ClockMode, Event, HsvRange, Scenario
from deploy.docs.scenario_tables import fields_table, tables, toml_value


def test_every_scenario_field_is_described() -> None:
    """Each row of every table (a nested table is a table of its own, not a row)."""
    bare = [
        f"{path or 'top level'}: {row.split(' | ')[0]}"
        for path, model in [*tables(Scenario, ""), ("[[events]]", Event)]
        for row in fields_table(model).splitlines()[2:]
        if not row.strip().strip("|").split(" | ")[2].strip()
    ]
    assert not bare, f"fields without a description: {bare}"


def test_every_table_of_a_scenario_is_listed_once_in_the_toml_order() -> None:
    paths = [path for path, _model in tables(Scenario, "")]
    assert paths[:6] == ["", "robot", "target", "marker", "camera", "camera.kinect"]
    assert "camera.calibration_error" in paths and paths.index("vision") > paths.index("camera")
    assert len(paths) == len(set(paths))


def test_defaults_read_as_they_are_written_in_toml() -> None:
    assert toml_value(True) == "true" and toml_value(None) == "unset"
    assert toml_value(ClockMode.LOCKSTEP) == '"lockstep"'
    assert toml_value([0.0, 1]) == "[0.0, 1]"
    hsv = HsvRange(lower=[0, 120, 30], upper=[8, 255, 255])
    assert toml_value([hsv]) == "[{lower = [0, 120, 30], upper = [8, 255, 255]}]"
    rows = fields_table(Event).splitlines()[2:]
    assert rows[0].startswith("| `at_s` | required | simulated time it starts (s) |")
    assert rows[2].startswith("| `duration_s` | unset | ")
