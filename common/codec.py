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

A frame **by reference** (version 2 of the layout) has the same prefix and map, but where the
pixels would start there is a msgpack map of a :class:`~common.frame_ring.FrameRef`: where the
pixels are in a shared-memory ring of the publisher's host (:mod:`common.frame_ring`).
:func:`decode` resolves it into the same message, whose image is then a read-only view of the
ring's slot (:meth:`~common.messages.ImageData.intact` says whether it still shows that
frame). A reference it cannot map (another host, a segment gone) raises
:class:`FrameUnreachable`, which carries the reference so that the caller can ask the publisher
for the whole frame (:mod:`common.publishers`); a slot overwritten before it was read is a
:class:`MessageError` like any unusable payload. :func:`whole_frame` turns a by-reference
payload into the ordinary layout (a copy of the pixels), for tools that keep payloads
(recordings).
"""

from __future__ import annotations

import functools
import struct
from typing import Any, TypeVar

import msgpack
from pydantic import BaseModel, ValidationError

from common.frame_ring import (
    FrameRef,
    RingReader,
    RingUnreachable,
    SlotOverwritten,
    shared_reader,
)
from common.messages import ImageData, ImageSpec

M = TypeVar("M", bound=BaseModel)

DEFAULT_MAX_BYTES = 1 << 16  # small control messages
FRAME_MAX_BYTES = 64 << 20  # RGB-D frames: 1920×1080 RGB + float32 depth fits with room

FRAME_MAGIC = b"UMYF"  # "U" is a msgpack integer: no msgpack map starts with it
FRAME_VERSION = 1
FRAME_VERSION_REF = 2  # the pixels are replaced by a FrameRef map
FRAME_ALIGN = 64  # the pixels start at a multiple of this (cache line; any dtype's alignment)
FRAME_MAX_HEADER_BYTES = 1 << 14
FRAME_PREFIX = struct.Struct("<4sHI")  # magic, version, header length


class MessageError(ValueError):
    """A payload that is not valid msgpack, too large, or fails validation."""


class FrameUnreachable(MessageError):
    """A frame by reference whose ring this process cannot map (another host, or the
    segment is gone): ``ref`` names the frame to ask its publisher for."""

    def __init__(self, message: str, ref: FrameRef) -> None:
        super().__init__(message)
        self.ref = ref


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


def by_reference(head: bytes, ref: FrameRef) -> bytes:
    """The by-reference payload of a frame whose :func:`frame_parts` head is ``head``."""
    _magic, _version, head_len = FRAME_PREFIX.unpack_from(head, 0)
    prefix = FRAME_PREFIX.pack(FRAME_MAGIC, FRAME_VERSION_REF, head_len)
    return prefix + head[FRAME_PREFIX.size :] + msgpack.packb(ref.to_map(), use_bin_type=True)


def is_by_reference(payload: bytes | bytearray | memoryview) -> bool:
    """Whether ``payload`` is a frame by reference (the pixels in a shared-memory ring)."""
    if len(payload) < FRAME_PREFIX.size or bytes(payload[:4]) != FRAME_MAGIC:
        return False
    return FRAME_PREFIX.unpack_from(payload, 0)[1] == FRAME_VERSION_REF


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
) -> tuple[dict, memoryview, int]:
    """(header map, pixel bytes or the reference's map, layout version) of a payload in the
    frame layout."""
    view = memoryview(payload)
    name = model.__name__
    if len(view) < FRAME_PREFIX.size:
        raise MessageError(f"{name}: frame of {len(view)} bytes, shorter than its prefix")
    _magic, version, head_len = FRAME_PREFIX.unpack_from(view, 0)
    if version not in (FRAME_VERSION, FRAME_VERSION_REF):
        raise MessageError(
            f"{name}: frame layout version {version}, expected {FRAME_VERSION} or "
            f"{FRAME_VERSION_REF}"
        )
    if head_len > FRAME_MAX_HEADER_BYTES or FRAME_PREFIX.size + head_len > len(view):
        raise MessageError(f"{name}: frame header of {head_len} bytes does not fit")
    head = _unpack_map(view[FRAME_PREFIX.size : FRAME_PREFIX.size + head_len], model)
    start = _aligned(FRAME_PREFIX.size + head_len)
    if start > len(view):
        raise MessageError(f"{name}: frame truncated before its pixels")
    return head, view[start:], version


def _frame_ref(body: memoryview, spec: ImageSpec, model: type[BaseModel], field: str) -> FrameRef:
    """The reference in a by-reference frame's body, checked against the header's spec."""
    try:
        ref = FrameRef.from_map(_unpack_map(body, model))
    except ValueError as exc:
        raise MessageError(f"{model.__name__}: {field}: {exc}") from exc
    if list(ref.shape) != spec.shape or ref.dtype != spec.dtype:
        raise MessageError(
            f"{model.__name__}: {field}: the reference is to a {ref.dtype} {list(ref.shape)} "
            f"image, the header says {spec.dtype} {spec.shape}"
        )
    return ref


def _ring_view(ref: FrameRef, rings: RingReader, model: type[BaseModel], field: str) -> memoryview:
    try:
        return rings.view(ref)
    except RingUnreachable as exc:
        raise FrameUnreachable(f"{model.__name__}: {field}: {exc}", ref) from exc
    except SlotOverwritten as exc:
        raise MessageError(f"{model.__name__}: {field}: {exc}") from exc


def _decode_frame(
    payload: bytes | bytearray | memoryview, model: type[M], field: str, rings: RingReader | None
) -> M:
    head, pixels, version = _split_frame(payload, model)
    spec_data = head.get(field)
    if not isinstance(spec_data, dict):
        raise MessageError(f"{model.__name__}: {field}: missing image shape and dtype")
    try:
        spec = ImageSpec.model_validate(spec_data)
    except ValidationError as exc:
        raise MessageError(_validation_error(model, exc, field)) from exc
    ref = None
    if version == FRAME_VERSION_REF:
        ref = _frame_ref(pixels, spec, model, field)
        rings = rings or shared_reader()
        pixels = _ring_view(ref, rings, model, field)
    try:
        image = head[field] = ImageData.from_view(spec, pixels.toreadonly())
    except ValueError as exc:
        raise MessageError(f"{model.__name__}: {field}: {exc}") from exc
    if ref is not None:
        image.in_ring(ref, rings)
    try:
        return model.model_validate(head)  # the ImageData instance is kept as it is
    except ValidationError as exc:
        raise MessageError(_validation_error(model, exc)) from exc


def decode(
    payload: bytes | bytearray | memoryview,
    model: type[M],
    max_bytes: int,
    rings: RingReader | None = None,
) -> M:
    """Validate ``payload`` as ``model``; oversized payloads are refused before unpacking.
    A frame by reference is resolved through ``rings`` (default: this process's
    :func:`~common.frame_ring.shared_reader`); :class:`FrameUnreachable` when it cannot be."""
    size = len(payload)
    if size > max_bytes:
        raise MessageError(f"{model.__name__}: payload of {size} bytes exceeds {max_bytes}")
    field = image_field(model)
    if field is not None and bytes(payload[: len(FRAME_MAGIC)]) == FRAME_MAGIC:
        return _decode_frame(payload, model, field, rings)
    data = _unpack_map(payload, model)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise MessageError(_validation_error(model, exc)) from exc


def whole_frame(
    payload: bytes | bytearray | memoryview, model: type[BaseModel], rings: RingReader | None = None
) -> bytes:
    """A by-reference frame ``payload`` as the ordinary layout (header, then a copy of the
    pixels, checked intact after the copy). :class:`FrameUnreachable` when the ring cannot
    be mapped, :class:`MessageError` when the frame is no longer in it."""
    field = image_field(model)
    if field is None:
        raise TypeError(f"{model.__name__} is not a camera frame")
    head, body, version = _split_frame(payload, model)
    if version != FRAME_VERSION_REF:
        return bytes(payload)
    try:
        spec = ImageSpec.model_validate(head.get(field))
    except ValidationError as exc:
        raise MessageError(_validation_error(model, exc, field)) from exc
    ref = _frame_ref(body, spec, model, field)
    rings = rings or shared_reader()
    pixels = bytes(_ring_view(ref, rings, model, field))
    if not rings.intact(ref):
        raise MessageError(f"{model.__name__}: {field}: frame {ref.seq} overwritten while copied")
    start = len(payload) - len(body)
    prefix = FRAME_PREFIX.pack(FRAME_MAGIC, FRAME_VERSION, FRAME_PREFIX.unpack_from(payload)[2])
    return prefix + bytes(payload[FRAME_PREFIX.size : start]) + pixels


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
