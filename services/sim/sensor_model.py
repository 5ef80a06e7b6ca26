"""Kinect v1 sensor model applied to perfect rendered images. Pure functions of (image, rng).

Depth: axial noise from Nguyen, Izadi & Lovell (2012), ``σ_z(z) = 0.0012 + 0.0019·(z − 0.4)²``
(m); disparity quantisation (the Kinect measures disparity in 1/8 pixel, so depth steps grow with
z²); invalid (0) depth outside the working range and in a band along depth discontinuities;
lateral noise (depth samples displaced by about 0.8 px). RGB: exposure (brightness), colour
temperature and Gaussian sensor noise.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from common.config import KinectConfig

# Disparity quantisation: d = f·b/z with f ≈ 580 px (IR camera) and b = 7.5 cm, measured in
# 1/8 px steps, so 1/z is quantised in steps of 1/(8·f·b).
DISPARITY_SCALE_M = 8.0 * 580.0 * 0.075


def axial_sigma_m(z_m: NDArray[np.floating]) -> NDArray[np.float64]:
    """Standard deviation of Kinect v1 depth along the ray (m), surface angle under 60°."""
    z = np.asarray(z_m, dtype=np.float64)
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


def quantise_depth(z_m: NDArray[np.floating]) -> NDArray[np.float64]:
    """Snap depth to the values a 1/8-pixel disparity can represent (0 stays 0)."""
    z = np.asarray(z_m, dtype=np.float64)
    out = np.zeros_like(z)
    valid = z > 0
    steps = np.maximum(np.round(DISPARITY_SCALE_M / z[valid]), 1.0)
    out[valid] = DISPARITY_SCALE_M / steps
    return out


def edge_mask(z_m: NDArray[np.floating], threshold_m: float, band_px: int) -> NDArray[np.bool_]:
    """Pixels within ``band_px`` of a depth jump larger than ``threshold_m`` (or of a hole)."""
    z = np.asarray(z_m, dtype=np.float32)
    kernel = np.ones((3, 3), np.uint8)
    local_max = cv2.dilate(z, kernel)
    local_min = cv2.erode(np.where(z > 0, z, np.float32(np.inf)).astype(np.float32), kernel)
    jumps = (local_max - local_min) > threshold_m
    if band_px > 0:
        jumps = cv2.dilate(jumps.astype(np.uint8), np.ones((2 * band_px + 1,) * 2, np.uint8)) > 0
    return jumps


def noisy_depth(
    z_m: NDArray[np.floating], model: KinectConfig, rng: np.random.Generator
) -> NDArray[np.float32]:
    """Perfect depth (m, 0 = nothing) → what a Kinect v1 would report."""
    z = np.asarray(z_m, dtype=np.float64)
    h, w = z.shape
    if model.lateral_noise_px > 0:
        dv = np.clip(np.rint(rng.normal(0.0, model.lateral_noise_px, (h, w))), -2, 2).astype(int)
        du = np.clip(np.rint(rng.normal(0.0, model.lateral_noise_px, (h, w))), -2, 2).astype(int)
        rows = np.clip(np.arange(h)[:, None] + dv, 0, h - 1)
        cols = np.clip(np.arange(w)[None, :] + du, 0, w - 1)
        z = z[rows, cols]
    dropped = edge_mask(z, model.edge_threshold_m, model.edge_dropout_px)
    valid = (z >= model.min_range_m) & (z <= model.max_range_m) & ~dropped
    noisy = z + rng.normal(0.0, 1.0, z.shape) * axial_sigma_m(z)
    noisy = np.where(valid, noisy, 0.0)
    if model.quantise:
        noisy = quantise_depth(noisy)
    return noisy.astype(np.float32)


def exposed_rgb(
    rgb: NDArray[np.uint8], model: KinectConfig, rng: np.random.Generator
) -> NDArray[np.uint8]:
    """Exposure, colour temperature and sensor noise on a perfect RGB image."""
    t = model.colour_temperature
    gains = model.brightness * np.array([1.0 - 0.25 * t, 1.0, 1.0 + 0.25 * t])
    out = rgb.astype(np.float32) * gains.astype(np.float32)
    if model.rgb_noise_sigma > 0:
        out += rng.normal(0.0, model.rgb_noise_sigma, out.shape).astype(np.float32)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
