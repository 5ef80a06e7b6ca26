"""The one marker type: its usable rule, its constructors, and its wire conversion, which must
leave every value of the recording format as it was."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from common.camera import CameraIntrinsics, project
from common.codec import DEFAULT_MAX_BYTES, decode, encode
from common.marker import Marker
from common.messages import Features, MarkerFeatures
from deploy.recording.read import iter_messages

K = CameraIntrinsics.from_fov(640, 480, 57.0)
REFERENCE = Path(__file__).resolve().parents[1] / "data" / "reference.mcap"


def square_points(centre_m: np.ndarray, size_m: float = 0.05) -> np.ndarray:
    h = size_m / 2
    return np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]]) + centre_m


@pytest.mark.parametrize(
    ("state", "fitted", "visible", "usable"),
    [
        ("visible", False, True, True),
        ("partial", True, False, True),
        ("partial", False, False, False),
        ("lost", False, False, False),
        ("no_depth", False, False, False),
    ],
)
def test_visible_and_usable_agree_with_the_wire(state, fitted, visible, usable) -> None:
    m = Marker.seen_at(square_points(np.array([0.0, 0.0, 0.6])), K)
    m = Marker(
        state=state,
        corners_px=m.corners_px,
        depth_m=m.depth_m,
        depth_sigma_m=m.depth_sigma_m,
        points_m=m.points_m,
        fitted=fitted,
    )
    assert (m.visible, m.usable) == (visible, usable)
    wire = m.to_wire()
    assert (wire.visible, wire.usable) == (visible, usable)


def test_unseen_has_zero_arrays_of_the_wire_shapes() -> None:
    m = Marker.unseen("lost", "no blob", occluded=True)
    assert m.corners_px.shape == (4, 2) and m.depth_m.shape == (4,)
    assert m.depth_sigma_m.shape == (4,) and m.points_m.shape == (4, 3)
    assert not any(a.any() for a in (m.corners_px, m.depth_m, m.depth_sigma_m, m.points_m))
    assert not m.usable and m.occluded and m.reason == "no blob"


def test_seen_at_projects_the_points() -> None:
    points = square_points(np.array([0.05, -0.02, 0.7]))
    m = Marker.seen_at(points, K, depth_sigma_m=np.full(4, 0.002))
    np.testing.assert_array_equal(m.corners_px, project(points, K))
    np.testing.assert_array_equal(m.depth_m, points[:, 2])
    np.testing.assert_array_equal(m.depth_sigma_m, np.full(4, 0.002))
    assert m.visible and not m.fitted and not m.occluded


def test_round_trip_keeps_every_value() -> None:
    rng = np.random.default_rng(3)
    points = square_points(np.array([0.03, 0.01, 0.55])) + rng.normal(0.0, 1e-3, (4, 3))
    m = Marker(
        state="partial",
        corners_px=project(points, K),
        depth_m=points[:, 2],
        depth_sigma_m=rng.uniform(1e-4, 3e-3, 4),
        points_m=points,
        occluded=True,
        fitted=True,
        reason="occluded",
    )
    back = Marker.from_wire(MarkerFeatures.model_validate_json(m.to_wire().model_dump_json()))
    for name in ("corners_px", "depth_m", "depth_sigma_m", "points_m"):
        got, sent = getattr(back, name), getattr(m, name)
        assert got.dtype == np.float64 and got.shape == sent.shape
        np.testing.assert_array_equal(got, sent)  # bit for bit
    assert (back.state, back.occluded, back.fitted, back.reason) == (
        "partial",
        True,
        True,
        "occluded",
    )


def test_a_marker_out_of_range_is_refused_on_the_wire() -> None:
    m = Marker.seen_at(square_points(np.array([0.0, 0.0, 0.6])), K)
    bad = Marker(
        state="visible",
        corners_px=m.corners_px,
        depth_m=np.array([0.6, np.nan, 0.6, 0.6]),
        depth_sigma_m=m.depth_sigma_m,
        points_m=m.points_m,
    )
    with pytest.raises(ValidationError):
        bad.to_wire()


def test_fields_are_named_not_positional() -> None:
    """The arrays have similar shapes: a positional call could swap two silently."""
    with pytest.raises(TypeError):
        Marker("visible", np.zeros((4, 2)), np.zeros(4), np.zeros(4), np.zeros((4, 3)))  # type: ignore[misc]


def test_the_reference_recording_goes_through_a_marker_unchanged() -> None:
    """Every recorded features message, each marker converted to a Marker and back, encodes
    to the same bytes: the wire format (and the recordings) are untouched."""
    states = set()
    n = 0
    for topic, _, _, payload in iter_messages(REFERENCE):
        if not topic.endswith("vision/features"):
            continue
        msg = decode(payload, Features, DEFAULT_MAX_BYTES)
        hand, target = Marker.from_wire(msg.hand), Marker.from_wire(msg.target)
        states |= {hand.state, target.state}
        again = msg.model_copy(update={"hand": hand.to_wire(), "target": target.to_wire()})
        assert encode(again) == encode(msg)
        n += 1
    assert n > 10 and "visible" in states
