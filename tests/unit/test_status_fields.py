"""The services' status fields as models: checked where they are built, each one described."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from deploy.docs.status_tables import STATUS_MODELS, fields_table, type_text
from services.actuation.status import ActuationStatus
from services.controller.status import ControllerStatus

ACTUATION = dict(
    deadman=False,
    deadman_stops=0,
    hold_stops=2,
    position_limit_clamps=1,
    velocity_clamps=0,
    acceleration_clamps=0,
    nonfinite_guards=0,
    damped_commands=3,
    saturated_joints=[1],
    manipulability=0.0137,
)


def test_a_service_cannot_answer_with_a_field_missing_misnamed_or_of_another_type() -> None:
    assert ActuationStatus(**ACTUATION).model_dump() == ACTUATION  # the wire's plain map
    missing = {k: v for k, v in ACTUATION.items() if k != "hold_stops"}
    with pytest.raises(ValidationError, match="hold_stops"):
        ActuationStatus(**missing)
    with pytest.raises(ValidationError, match="hold_stop"):
        ActuationStatus(**ACTUATION, hold_stop=1)
    with pytest.raises(ValidationError, match="saturated_joints"):
        ActuationStatus(**{**ACTUATION, "saturated_joints": ["wrist"]})


def test_every_field_of_every_status_is_described() -> None:
    for who, model, _path in STATUS_MODELS:
        bare = [n for n, f in model.model_fields.items() if not (f.description or "").strip()]
        assert not bare, f"{who}: {bare} without a description"


def test_types_read_as_words() -> None:
    fields = ControllerStatus.model_fields
    assert type_text(fields["error_px_rms"].annotation) == "number"
    assert type_text(fields["hold_since_s"].annotation) == "number or none"
    assert type_text(fields["pairings_reachable"].annotation) == "list of true/false or none"
    assert type_text(fields["pairing"].annotation) == "integer or none"
    assert type_text(dict[str, int]) == "map of integer"
    assert type_text(dict[str, ActuationStatus]) == "map of `ActuationStatus`"
    table = fields_table(ActuationStatus).splitlines()
    assert table[0] == "| field | type | what |"
    assert [row.split(" | ")[0] for row in table[2:]] == [f"| `{n}`" for n in ACTUATION]
