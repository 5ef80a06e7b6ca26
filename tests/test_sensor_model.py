"""The Kinect v1 sensor model: statistics it must reproduce, and determinism."""

from __future__ import annotations

import numpy as np

from common.config import KinectConfig
from services.sim.sensor_model import (
    axial_sigma_m,
    edge_mask,
    exposed_rgb,
    noisy_depth,
    quantise_depth,
)


def test_axial_noise_follows_the_published_model() -> None:
    model = KinectConfig(enabled=True, lateral_noise_px=0.0, quantise=False, edge_dropout_px=0)
    for z in (0.6, 1.0, 2.0):
        flat = np.full((200, 200), z, np.float32)
        out = noisy_depth(flat, model, np.random.default_rng(1))
        assert abs(out.mean() - z) < 0.1 * axial_sigma_m(z)
        assert abs(out.std() / axial_sigma_m(z) - 1.0) < 0.05
    assert np.isclose(axial_sigma_m(2.0), 0.0012 + 0.0019 * 1.6**2)


def test_quantisation_steps_grow_with_depth_squared() -> None:
    z = np.linspace(0.5, 3.0, 20000)
    q = quantise_depth(z)
    step_near = np.diff(np.unique(q[z < 0.6])).max()
    step_far = np.diff(np.unique(q[z > 2.9])).max()
    assert 0.0005 < step_near < 0.0015 and 0.02 < step_far < 0.03
    assert (step_far / step_near) > 20
    assert quantise_depth(np.zeros(3)).tolist() == [0.0, 0.0, 0.0]


def test_range_limits_and_edges_are_invalid() -> None:
    model = KinectConfig(enabled=True, lateral_noise_px=0.0, edge_dropout_px=2)
    depth = np.full((60, 80), 1.0, np.float32)
    depth[:, 40:] = 2.0  # a step: an edge at column 40
    depth[:5] = 0.3  # closer than the working range
    out = noisy_depth(depth, model, np.random.default_rng(0))
    assert np.all(out[:5] == 0)
    assert np.all(out[10:, 38:42] == 0)  # the band along the edge
    assert np.all(out[10:, :30] > 0) and np.all(out[10:, 50:] > 0)
    assert edge_mask(depth, 0.03, 0)[20, 39] and not edge_mask(depth, 0.03, 0)[20, 10]


def test_same_seed_same_images_and_lighting_changes_colours() -> None:
    depth = np.full((40, 50), 0.8, np.float32)
    rgb = np.full((40, 50, 3), 120, np.uint8)
    model = KinectConfig(enabled=True, brightness=1.5, colour_temperature=0.5)
    a = (
        noisy_depth(depth, model, np.random.default_rng(7)),
        exposed_rgb(rgb, model, np.random.default_rng(7)),
    )
    b = (
        noisy_depth(depth, model, np.random.default_rng(7)),
        exposed_rgb(rgb, model, np.random.default_rng(7)),
    )
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    mean = a[1].reshape(-1, 3).mean(axis=0)
    assert mean[2] > mean[1] > mean[0] > 120  # brighter, and cooler: blue up, red down
    dark = exposed_rgb(
        rgb, KinectConfig(brightness=0.5, rgb_noise_sigma=0.0), np.random.default_rng(0)
    )
    assert np.all(dark == 60)
