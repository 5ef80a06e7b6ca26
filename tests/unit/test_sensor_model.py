"""The Kinect v1 sensor model: statistics it must reproduce, and determinism."""

from __future__ import annotations

import numpy as np
import pytest

from common.config import KinectConfig
from services.sim.sensor_model import (
    DISPARITY_SCALE_M,
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


# --- statistics that must not drift (the model is drawn from raw bits, not rng.normal) -------


def _reference_edge_mask(z: np.ndarray, threshold_m: float, band_px: int) -> np.ndarray:
    """The original numpy formulation: 3×3 max minus 3×3 min of the non-zero depths."""
    import cv2

    kernel = np.ones((3, 3), np.uint8)
    local_max = cv2.dilate(z, kernel)
    local_min = cv2.erode(np.where(z > 0, z, np.float32(np.inf)).astype(np.float32), kernel)
    jumps = (local_max - local_min) > threshold_m
    if band_px > 0:
        jumps = cv2.dilate(jumps.astype(np.uint8), np.ones((2 * band_px + 1,) * 2, np.uint8)) > 0
    return jumps


def _scene(h: int, w: int) -> np.ndarray:
    """Ramps, boxes (steps of 0.6 and 0.4 m), and a hole (0) with a far background."""
    z = np.full((h, w), 2.5, np.float32)
    v, u = np.mgrid[0:h, 0:w]
    z[:, : w // 3] = 0.6 + 1.2 * u[:, : w // 3] / w
    z[h // 4 : h // 2, w // 3 : 2 * w // 3] = 1.1
    z[h // 2 :, w // 2 :] = 1.7
    z[(u - w // 4) ** 2 + (v - h // 4) ** 2 < (h // 10) ** 2] = 0.0
    return z


def test_edge_mask_matches_the_reference_formulation() -> None:
    z = _scene(120, 160)
    z[60:, :40] += np.linspace(0.0, 0.5, 40, dtype=np.float32)  # a slanted plane: no edge
    for threshold, band in ((0.03, 0), (0.03, 2), (0.5, 1), (0.45, 3)):
        assert np.array_equal(
            edge_mask(z, threshold, band), _reference_edge_mask(z, threshold, band)
        )


def _lateral_probabilities(sigma: float) -> np.ndarray:
    """P(d), d = -2..2, of clip(rint(N(0, sigma)), -2, 2), computed here independently."""
    from math import erf, sqrt

    def cdf(x: float) -> float:
        return 0.5 * (1.0 + erf(x / (sigma * sqrt(2.0))))

    edges = [-np.inf, -1.5, -0.5, 0.5, 1.5, np.inf]
    return np.diff([0.0 if e == -np.inf else 1.0 if e == np.inf else cdf(e) for e in edges])


def _observed_offsets(sigma: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(du, dv) of every interior pixel, decoded from a depth image whose value encodes
    (u mod 5, v mod 5) in 25 levels 32 mm apart between 0.45 and 1.22 m: the axial noise there
    is at most 2.5 mm and bounded (4.85 σ), so no level can be mistaken for another."""
    h, w = 480, 640
    v, u = np.mgrid[0:h, 0:w]
    code = (u % 5) + 5 * (v % 5)
    depth = (0.45 + 0.032 * code).astype(np.float32)
    model = KinectConfig(enabled=True, lateral_noise_px=sigma, quantise=False, edge_threshold_m=5.0)
    out = noisy_depth(depth, model, np.random.default_rng(seed))
    seen = np.rint((out - 0.45) / 0.032).astype(int)
    assert seen.min() >= 0 and seen.max() <= 24
    inner = (slice(2, h - 2), slice(2, w - 2))
    du = ((seen % 5 - u % 5 + 2) % 5 - 2)[inner]
    dv = ((seen // 5 - v % 5 + 2) % 5 - 2)[inner]
    return du.ravel(), dv.ravel()


def test_lateral_offsets_follow_the_rounded_clipped_normal() -> None:
    for sigma in (0.3, 0.8, 1.5):
        du, dv = _observed_offsets(sigma, seed=3)
        n = du.size
        p = _lateral_probabilities(sigma)
        for d in (du, dv):
            freq = np.bincount(d + 2, minlength=5) / n
            tolerance = 5.0 * np.sqrt(p * (1 - p) / n) + 1e-5
            assert np.all(np.abs(freq - p) < tolerance), (sigma, freq, p)
        joint = np.bincount((dv + 2) * 5 + (du + 2), minlength=25).reshape(5, 5) / n
        expected = np.outer(p, p)
        tolerance = 5.0 * np.sqrt(expected * (1 - expected) / n) + 1e-5
        assert np.all(np.abs(joint - expected) < tolerance), sigma  # u and v independent
        assert abs(np.corrcoef(du, dv)[0, 1]) < 0.01


def test_lateral_offset_table_holds_the_exact_probabilities() -> None:
    from services.sim.sensor_model import _lateral_table, lateral_offset_probabilities

    for sigma in (0.2, 0.8, 2.0, 5.0):
        p = _lateral_probabilities(sigma)
        assert np.allclose(lateral_offset_probabilities(sigma), p, atol=1e-12)
        table = _lateral_table(sigma)
        assert table.size == 65536
        pairs = table.view(np.int16).reshape(-1, 2).astype(int)  # (du, dv)
        counts = np.zeros((5, 5))
        np.add.at(counts, (pairs[:, 1] + 2, pairs[:, 0] + 2), 1)
        assert np.all(np.abs(counts / 65536 - np.outer(p, p)) < 1.0 / 65536), sigma


def test_lateral_offsets_are_independent_between_neighbours() -> None:
    du, dv = _observed_offsets(0.8, seed=4)
    w = 640 - 4
    for d in (du, dv):
        grid = d.reshape(-1, w).astype(float)
        assert abs(np.corrcoef(grid[:, 1:].ravel(), grid[:, :-1].ravel())[0, 1]) < 0.01
        assert abs(np.corrcoef(grid[1:].ravel(), grid[:-1].ravel())[0, 1]) < 0.01


def test_axial_noise_is_gaussian_with_the_published_sigma_at_many_depths() -> None:
    model = KinectConfig(
        enabled=True, lateral_noise_px=0.0, quantise=False, edge_dropout_px=0, max_range_m=4.0
    )
    rng = np.random.default_rng(5)
    for z in (0.45, 0.8, 1.5, 2.5, 3.5):
        out = noisy_depth(np.full((480, 640), z, np.float32), model, rng).astype(np.float64)
        sigma = axial_sigma_m(z)
        err = (out - z) / sigma
        assert abs(err.mean()) < 0.01, z
        assert abs(err.std() - 1.0) < 0.01, z
        assert abs(np.mean(np.abs(err) < 1.0) - 0.6827) < 0.005, z
        assert abs(np.mean(np.abs(err) > 2.0) - 0.0455) < 0.003, z
        assert abs(np.mean(err**4) / np.mean(err**2) ** 2 - 3.0) < 0.06, z  # kurtosis
        assert np.abs(err).max() < 5.0  # bounded, as documented (4.85 σ)


@pytest.mark.parametrize("shape", [(240, 320), (480, 640)])  # one band, two bands
def test_quantised_depths_are_exactly_disparity_levels(shape: tuple[int, int]) -> None:
    model = KinectConfig(enabled=True)
    out = noisy_depth(_scene(*shape), model, np.random.default_rng(6))
    valid = out[out > 0]
    assert valid.size > 0.7 * out.size
    steps = np.rint(DISPARITY_SCALE_M / valid.astype(np.float64))
    levels = (DISPARITY_SCALE_M / steps).astype(np.float32)  # float32 of the exact S/k
    assert np.array_equal(valid, levels)
    k = np.arange(1, 2000)
    assert np.array_equal(
        np.float32(DISPARITY_SCALE_M) / k.astype(np.float32),
        (DISPARITY_SCALE_M / k).astype(np.float32),
    )


@pytest.mark.parametrize("shape", [(240, 320), (480, 640)])
def test_invalid_pixels_are_exactly_those_out_of_range_or_near_edges(
    shape: tuple[int, int],
) -> None:
    model = KinectConfig(enabled=True, lateral_noise_px=0.0, min_range_m=0.7, max_range_m=2.0)
    depth = _scene(*shape)
    out = noisy_depth(depth, model, np.random.default_rng(7))
    expected_invalid = (
        (depth < 0.7)
        | (depth > 2.0)
        | _reference_edge_mask(depth, model.edge_threshold_m, model.edge_dropout_px)
    )
    assert np.array_equal(out == 0, expected_invalid)


def test_rgb_noise_and_gains_statistics() -> None:
    flat = np.full((480, 640, 3), 100, np.uint8)
    for sigma, brightness, temperature in ((1.0, 1.0, 0.0), (2.0, 1.3, 0.4), (5.0, 0.7, -0.6)):
        model = KinectConfig(
            rgb_noise_sigma=sigma, brightness=brightness, colour_temperature=temperature
        )
        out = exposed_rgb(flat, model, np.random.default_rng(8)).astype(np.float64)
        gains = brightness * np.array([1 - 0.25 * temperature, 1.0, 1 + 0.25 * temperature])
        err = out - 100.0 * gains  # rounding adds a uniform ±0.5: variance σ² + 1/12
        expected_std = np.sqrt(sigma**2 + 1.0 / 12.0)
        for c in range(3):
            e = err[..., c]
            assert abs(e.mean()) < 4.0 * expected_std / np.sqrt(e.size), (sigma, c)  # 4 SE
            assert abs(e.std() / expected_std - 1.0) < 0.02, (sigma, c)
            assert abs(np.mean(np.abs(e) > 2 * sigma) - 0.0455) < 0.01 + 0.05 / sigma, (sigma, c)
        # channels independent of each other and of their neighbours
        assert abs(np.corrcoef(err[..., 0].ravel(), err[..., 2].ravel())[0, 1]) < 0.01
        assert abs(np.corrcoef(err[:, 1:, 1].ravel(), err[:, :-1, 1].ravel())[0, 1]) < 0.01


def test_rgb_rounds_and_clips_like_the_formula() -> None:
    ramp = np.tile(np.arange(256, dtype=np.uint8), (4, 1))
    rgb = np.dstack([ramp, ramp[:, ::-1], ramp])
    noiseless = exposed_rgb(
        rgb,
        KinectConfig(rgb_noise_sigma=0.0, brightness=1.7, colour_temperature=0.3),
        np.random.default_rng(0),
    )
    gains = np.float32(1.7) * np.array([1 - 0.075, 1.0, 1 + 0.075], np.float32)
    assert np.array_equal(noiseless, np.clip(np.rint(rgb * gains), 0, 255).astype(np.uint8))
    noisy = exposed_rgb(
        rgb, KinectConfig(rgb_noise_sigma=3.0, brightness=3.0), np.random.default_rng(1)
    )
    assert noisy.dtype == np.uint8 and np.all(noisy[:, 200:, 0] == 255)  # saturated


def test_odd_sizes_and_successive_calls() -> None:
    model = KinectConfig(enabled=True, colour_temperature=0.2)
    rng = np.random.default_rng(9)
    depth = np.full((7, 9), 1.2, np.float32)
    rgb = np.full((7, 9, 3), 80, np.uint8)
    a, b = noisy_depth(depth, model, rng), noisy_depth(depth, model, rng)
    assert a.shape == (7, 9) and a.dtype == np.float32 and not np.array_equal(a, b)
    c, d = exposed_rgb(rgb, model, rng), exposed_rgb(rgb, model, rng)
    assert c.shape == (7, 9, 3) and not np.array_equal(c, d)
    # outputs are fresh arrays: a later call leaves an earlier image alone
    kept = a.copy()
    noisy_depth(depth, model, rng)
    assert np.array_equal(a, kept)


def test_images_written_into_given_arrays_are_those_of_fresh_ones() -> None:
    """``out``: the model's images written where asked (a camera frame's ring slot), the same
    values; an array that does not fit, or the input itself, is refused."""
    model = KinectConfig(enabled=True, colour_temperature=0.2)
    depth = _scene(480, 640)
    rgb = np.random.default_rng(13).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    fresh = noisy_depth(depth, model, np.random.default_rng(5))
    depth_out = np.full(depth.shape, -1.0, np.float32)
    assert noisy_depth(depth, model, np.random.default_rng(5), out=depth_out) is depth_out
    assert np.array_equal(depth_out, fresh)
    rgb_out = np.zeros_like(rgb)
    assert exposed_rgb(rgb, model, np.random.default_rng(6), out=rgb_out) is rgb_out
    assert np.array_equal(rgb_out, exposed_rgb(rgb, model, np.random.default_rng(6)))
    noiseless = KinectConfig(enabled=True, rgb_noise_sigma=0.0, brightness=1.2)
    assert exposed_rgb(rgb, noiseless, np.random.default_rng(6), out=rgb_out) is rgb_out
    assert np.array_equal(rgb_out, exposed_rgb(rgb, noiseless, np.random.default_rng(6)))
    with pytest.raises(ValueError, match="cannot write"):
        noisy_depth(depth, model, np.random.default_rng(5), out=depth_out[:, :-1])
    with pytest.raises(ValueError, match="cannot write"):
        exposed_rgb(rgb, model, np.random.default_rng(6), out=rgb_out.astype(np.float32))
    with pytest.raises(ValueError, match="its own input"):
        noisy_depth(depth, model, np.random.default_rng(5), out=depth)


def test_helper_thread_changes_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    """Large images are shared with a helper thread; the images are the same without it."""
    import services.sim.sensor_model as sensor_model

    model = KinectConfig(enabled=True, colour_temperature=-0.3)
    depth = _scene(480, 640)
    rgb = np.random.default_rng(10).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    shared = (
        noisy_depth(depth, model, np.random.default_rng(11)),
        exposed_rgb(rgb, model, np.random.default_rng(12)),
    )
    monkeypatch.setattr(sensor_model, "_helper_enabled", False)
    alone = (
        noisy_depth(depth, model, np.random.default_rng(11)),
        exposed_rgb(rgb, model, np.random.default_rng(12)),
    )
    assert np.array_equal(shared[0], alone[0]) and np.array_equal(shared[1], alone[1])
