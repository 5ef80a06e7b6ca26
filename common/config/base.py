"""What every scenario table shares: a strict, frozen pydantic model (an unknown field is an
error naming its path, not a value silently ignored) and the list shapes they use."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Joints6 = Annotated[list[float], Field(min_length=6, max_length=6)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)
