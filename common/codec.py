"""msgpack codec for the pydantic wire models, with a raw layout for camera frames.

``encode`` turns a model into bytes; ``decode`` turns bytes back into a validated model or
raises :class:`MessageError`, the one error type nodes catch, count and log.

Messages carry one msgpack map each, except camera frames (models with an :class:`ImageData`
field: ``RgbFrame``, ``DepthFrame``), which are a small msgpack header followed by the raw
pixels, so that neither end copies the image through msgpack::

    b"UMYF" | u16 version | u32 n | msgpack map (n bytes) | zero padding to 64 | pixels

The map is the message without the image's ``data`` (its ``shape`` and ``dtype`` stay); the
pixels run from the first 64-byte boundary after the map to the end of the payload. Decoding
validates the map like any message (pydantic: ranges, shapes against intrinsics), checks that
the pixel bytes match shape and dtype exactly, and returns the image as a read-only view into
the payload (``np.frombuffer``), without a copy. A frame in the plain msgpack form (recordings
made before this layout) is still accepted.
"""

from __future__ import annotations

import functools
import struct
from typing import Any, TypeVar

import msgpack
from pydantic import BaseModel, ValidationError

from common.messages import ImageData, ImageSpec

M = TypeVar("M", bound=BaseModel)

DEFAULT_MAX_BYTES = 1 << 16  # small control messages
FRAME_MAX_BYTES = 64 << 20  # RGB-D frames: 1920×1080 RGB + float32 depth fits with room

FRAME_MAGIC = b"UMYF"  # "U" is a msgpack integer: no msgpack map starts with it
FRAME_VERSION = 1
FRAME_ALIGN = 64  # the pixels start at a multiple of this (cache line; any dtype's alignment)
FRAME_MAX_HEADER_BYTES = 1 << 14
FRAME_PREFIX = struct.Struct("<4sHI")  # magic, version, header length


class MessageError(ValueError):
    """A payload that is not valid msgpack, too large, or fails validation."""


@functools.cache
def image_field(model: type[BaseModel]) -> str | None:
    """The name of ``model``'s :class:`ImageData` field (camera frames), else None."""
    for name, info in model.model_fields.items():
        if info.annotation is ImageData:
            return name
    return None


def _aligned(n: int) -> int:
    return -(-n // FRAME_ALIGN) * FRAME_ALIGN


def encode(message: BaseModel) -> bytes:
    if image_field(type(message)) is None:
        return msgpack.packb(message.model_dump(mode="python"), use_bin_type=True)
    # One copy of the pixels (the join); ImageData.view_of means none before it.
    return b"".join(frame_parts(message))


def frame_parts(message: BaseModel) -> tuple[bytes, memoryview]:
    """A camera frame's payload in two pieces, to be written one after the other: prefix,
    header map and padding; then the pixels (a view, not a copy)."""
    field = image_field(type(message))
    if field is None:
        raise TypeError(f"{type(message).__name__} is not a camera frame")
    head = msgpack.packb(
        message.model_dump(mode="python", exclude={field: {"data"}}), use_bin_type=True
    )
    used = FRAME_PREFIX.size + len(head)
    prefix = FRAME_PREFIX.pack(FRAME_MAGIC, FRAME_VERSION, len(head))
    return prefix + head + bytes(_aligned(used) - used), memoryview(getattr(message, field).data)


def _validation_error(model: type[BaseModel], exc: ValidationError, prefix: str = "") -> str:
    first = exc.errors()[0]
    loc = ".".join([prefix, *(str(p) for p in first["loc"])] if prefix else map(str, first["loc"]))
    return f"{model.__name__}: {loc or '(root)'}: {first['msg']} ({exc.error_count()} error(s))"


def _unpack_map(data: bytes | bytearray | memoryview, model: type[BaseModel]) -> dict:
    try:
        out = msgpack.unpackb(data, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types for bad input
        raise MessageError(
            f"{model.__name__}: not valid msgpack ({exc.__class__.__name__})"
        ) from exc
    if not isinstance(out, dict):
        raise MessageError(f"{model.__name__}: expected a map, got {type(out).__name__}")
    return out


def _split_frame(
    payload: bytes | bytearray | memoryview, model: type[BaseModel]
) -> tuple[dict, memoryview]:
    """(header map, pixel bytes) of a payload in the frame layout."""
    view = memoryview(payload)
    name = model.__name__
    if len(view) < FRAME_PREFIX.size:
        raise MessageError(f"{name}: frame of {len(view)} bytes, shorter than its prefix")
    _magic, version, head_len = FRAME_PREFIX.unpack_from(view, 0)
    if version != FRAME_VERSION:
        raise MessageError(f"{name}: frame layout version {version}, expected {FRAME_VERSION}")
    if head_len > FRAME_MAX_HEADER_BYTES or FRAME_PREFIX.size + head_len > len(view):
        raise MessageError(f"{name}: frame header of {head_len} bytes does not fit")
    head = _unpack_map(view[FRAME_PREFIX.size : FRAME_PREFIX.size + head_len], model)
    start = _aligned(FRAME_PREFIX.size + head_len)
    if start > len(view):
        raise MessageError(f"{name}: frame truncated before its pixels")
    return head, view[start:]


def _decode_frame(payload: bytes | bytearray | memoryview, model: type[M], field: str) -> M:
    head, pixels = _split_frame(payload, model)
    spec_data = head.get(field)
    if not isinstance(spec_data, dict):
        raise MessageError(f"{model.__name__}: {field}: missing image shape and dtype")
    try:
        spec = ImageSpec.model_validate(spec_data)
    except ValidationError as exc:
        raise MessageError(_validation_error(model, exc, field)) from exc
    try:
        head[field] = ImageData.from_view(spec, pixels.toreadonly())
    except ValueError as exc:
        raise MessageError(f"{model.__name__}: {field}: {exc}") from exc
    try:
        return model.model_validate(head)  # the ImageData instance is kept as it is
    except ValidationError as exc:
        raise MessageError(_validation_error(model, exc)) from exc


def decode(payload: bytes | bytearray | memoryview, model: type[M], max_bytes: int) -> M:
    """Validate ``payload`` as ``model``; oversized payloads are refused before unpacking."""
    size = len(payload)
    if size > max_bytes:
        raise MessageError(f"{model.__name__}: payload of {size} bytes exceeds {max_bytes}")
    field = image_field(model)
    if field is not None and bytes(payload[: len(FRAME_MAGIC)]) == FRAME_MAGIC:
        return _decode_frame(payload, model, field)
    data = _unpack_map(payload, model)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise MessageError(_validation_error(model, exc)) from exc


def unpack(payload: bytes | bytearray | memoryview) -> dict[str, Any] | None:
    """A payload as plain data, without validation (a frame: its header map, no pixels);
    None when it is neither form. For tools that only read headers (recording, replay)."""
    try:
        if bytes(payload[: len(FRAME_MAGIC)]) == FRAME_MAGIC:
            return _split_frame(payload, BaseModel)[0]
        data = msgpack.unpackb(payload, raw=False)
    except Exception:  # not a message: the caller decides what that means
        return None
    return data if isinstance(data, dict) else None
