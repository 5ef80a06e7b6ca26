"""msgpack codec for the pydantic wire models.

``encode`` turns a model into bytes; ``decode`` turns bytes back into a validated model or
raises :class:`MessageError`, the one error type nodes catch, count and log.
"""

from __future__ import annotations

from typing import TypeVar

import msgpack
from pydantic import BaseModel, ValidationError

M = TypeVar("M", bound=BaseModel)

DEFAULT_MAX_BYTES = 1 << 16  # small control messages
FRAME_MAX_BYTES = 64 << 20  # RGB-D frames: 1920×1080 RGB + float32 depth fits with room


class MessageError(ValueError):
    """A payload that is not valid msgpack, too large, or fails validation."""


def encode(message: BaseModel) -> bytes:
    return msgpack.packb(message.model_dump(mode="python"), use_bin_type=True)


def decode(payload: bytes | bytearray | memoryview, model: type[M], max_bytes: int) -> M:
    """Validate ``payload`` as ``model``; oversized payloads are refused before unpacking."""
    size = len(payload)
    if size > max_bytes:
        raise MessageError(f"{model.__name__}: payload of {size} bytes exceeds {max_bytes}")
    try:
        data = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types for bad input
        raise MessageError(
            f"{model.__name__}: not valid msgpack ({exc.__class__.__name__})"
        ) from exc
    if not isinstance(data, dict):
        raise MessageError(f"{model.__name__}: expected a map, got {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        loc = ".".join(str(p) for p in first["loc"]) or "(root)"
        raise MessageError(
            f"{model.__name__}: {loc}: {first['msg']} ({exc.error_count()} error(s))"
        ) from exc
