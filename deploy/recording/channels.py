"""What a recording holds: one MCAP channel per data key (topic = the Zenoh key), the key's
message model, the encodings and the metadata record's name. Shared by the recorder
(:mod:`deploy.recording.record`) and everything that reads a recording back
(:mod:`deploy.recording.read`, the replay, the plots, the Foxglove export)."""

from __future__ import annotations

from pydantic import BaseModel

from common import keys as data_keys
from common.keys import Keys
from common.messages import (
    DepthFrame,
    EndEffectorTwist,
    Features,
    JointState,
    JointVelocityCommand,
    RgbFrame,
    SimTruth,
)

METADATA_NAME = "umay"
MESSAGE_ENCODING = "msgpack"
# Camera frames: a msgpack header, then the raw pixels (common.codec's frame layout).
FRAME_MESSAGE_ENCODING = "umay-frame"
SCHEMA_ENCODING = "jsonschema"
PROFILE = "umay"

# Key suffix (after the prefix) → model: the data keys, the only ones recorded.
DATA_SUFFIXES: dict[str, type[BaseModel]] = {
    data_keys.RGB: RgbFrame,
    data_keys.DEPTH: DepthFrame,
    data_keys.JOINT_STATE: JointState,
    data_keys.TRUTH: SimTruth,
    data_keys.FEATURES: Features,
    data_keys.TWIST: EndEffectorTwist,
    data_keys.JOINT_COMMAND: JointVelocityCommand,
}


def model_for_key(keys: Keys, key: str) -> type[BaseModel] | None:
    """The message model of a data key under ``keys.prefix``; None for anything else (status
    queries, liveliness, keys under another prefix)."""
    prefix = keys.prefix + "/"
    if not key.startswith(prefix):
        return None
    return DATA_SUFFIXES.get(key[len(prefix) :])


def split_data_key(key: str) -> tuple[str, str, type[BaseModel]] | None:
    """``"<prefix>/sim/rgb"`` → ``("<prefix>", "sim/rgb", RgbFrame)``, whatever the prefix;
    None when the key is not a data key."""
    parts = key.split("/")
    if len(parts) < 3:
        return None
    suffix = "/".join(parts[-2:])
    model = DATA_SUFFIXES.get(suffix)
    return None if model is None else ("/".join(parts[:-2]), suffix, model)
