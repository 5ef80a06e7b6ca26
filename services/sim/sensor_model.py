"""Kinect v1 sensor model applied to perfect rendered images. Pure functions of (image, rng).

Depth: axial noise from Nguyen, Izadi & Lovell (2012), ``σ_z(z) = 0.0012 + 0.0019·(z − 0.4)²``
(m); disparity quantisation (the Kinect measures disparity in 1/8 pixel, so depth steps grow with
z²); invalid (0) depth outside the working range and in a band along depth discontinuities;
lateral noise (each depth sample read from a neighbour displaced by ``rint(N(0, σ_l))`` pixels
in u and, independently, in v, clipped to ±2). RGB: exposure (brightness), colour temperature
and Gaussian sensor noise, rounded and clipped to uint8.

The simulated camera runs at 30 Hz with the model on, so the work is done in float32 and uint8
by OpenCV kernels, in scratch buffers kept between calls (per thread), and large images are
done in two bands of rows, the lower one on a helper thread. Randomness: raw 64-bit words of
the passed generator (``rng.bit_generator.random_raw``; nothing global); the lower band draws
from a PCG64 seeded with two of those words, so that both bands draw at the same time. The same
generator state therefore gives bit-identical images, whether or not the helper thread is used.
The words are read as 16-bit uniforms k/65536 and turned into the distributions without
``rng.normal`` (far slower):

- Gaussian samples (axial depth noise, RGB sensor noise) by Box–Muller on pairs of uniforms
  taken at the centres of their cells, u = (k + 0.5)/65536: ``r = sqrt(−2 ln u1)``,
  ``θ = 2π u2``, samples ``r cos θ`` and ``r sin θ``. The radius is the exact Rayleigh quantile
  at 65536 levels, the angle has 65536 levels: each sample's CDF is within 1e-6 of the normal
  one, its variance is 1 − 5e-6, and it never exceeds 4.85 σ (the exact normal does with
  probability 1.2e-6). As good as inverse-CDF sampling from a 65536-entry quantile table, and
  cheaper here: a handful of vectorised float32 passes instead of a per-sample gather.
- Lateral offsets from one 16-bit uniform per pixel through a 65536-entry table of (du, dv)
  pairs, in which each of the 25 outcomes fills round(65536·P(du)·P(dv)) entries, P being the
  exact probabilities of the rounded, clipped normal: exact to within 1/65536 (independent u
  and v to the same precision).
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

from common.config import KinectConfig

# Disparity quantisation: d = f·b/z with f ≈ 580 px (IR camera) and b = 7.5 cm, measured in
# 1/8 px steps, so 1/z is quantised in steps of 1/(8·f·b).
DISPARITY_SCALE_M = 8.0 * 580.0 * 0.075

# σ_z(z) = AXIAL_SIGMA_0_M + AXIAL_SIGMA_QUAD·(z − AXIAL_SIGMA_Z0_M)² (Nguyen et al. 2012).
AXIAL_SIGMA_0_M = 0.0012
AXIAL_SIGMA_QUAD = 0.0019  # 1/m
AXIAL_SIGMA_Z0_M = 0.4

LATERAL_CLIP_PX = 2
_U16 = 65536
_KERNEL_3X3 = np.ones((3, 3), np.uint8)
# Images of at least this many values (and 64 rows) are done in two bands of rows, the lower
# one on a helper thread, drawing from a generator seeded by the passed one.
_SPLIT_MIN = 1 << 17
_helper_enabled = True  # False: both bands on the calling thread (same images)

_local = threading.local()
_helper: ThreadPoolExecutor | None = None
_helper_lock = threading.Lock()


def _forget_helper() -> None:  # a forked child has no helper thread: start a new one
    global _helper, _helper_lock
    _helper, _helper_lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_helper)


def axial_sigma_m(z_m: NDArray[np.floating]) -> NDArray[np.float64]:
    """Standard deviation of Kinect v1 depth along the ray (m), surface angle under 60°."""
    z = np.asarray(z_m, dtype=np.float64)
    return AXIAL_SIGMA_0_M + AXIAL_SIGMA_QUAD * (z - AXIAL_SIGMA_Z0_M) ** 2


def quantise_depth(z_m: NDArray[np.floating]) -> NDArray[np.float64]:
    """Snap depth to the values a 1/8-pixel disparity can represent (0 stays 0)."""
    z = np.asarray(z_m, dtype=np.float64)
    out = np.zeros_like(z)
    valid = z > 0
    steps = np.maximum(np.round(DISPARITY_SCALE_M / z[valid]), 1.0)
    out[valid] = DISPARITY_SCALE_M / steps
    return out


def edge_mask(z_m: NDArray[np.floating], threshold_m: float, band_px: int) -> NDArray[np.bool_]:
    """Pixels within ``band_px`` of a depth jump: where the largest depth of the 3×3
    neighbourhood exceeds its smallest non-zero depth by more than ``threshold_m``."""
    z = np.ascontiguousarray(z_m, dtype=np.float32)
    return _edge_mask_u8(z, threshold_m, band_px) > 0


def lateral_offset_probabilities(sigma_px: float) -> NDArray[np.float64]:
    """P(d), d = −2 … 2, of ``clip(rint(N(0, sigma_px)), −2, 2)``: one axis of lateral noise."""
    edges = np.arange(-LATERAL_CLIP_PX, LATERAL_CLIP_PX) + 0.5  # −1.5 … 1.5
    cdf = [0.5 * math.erfc(-e / (sigma_px * math.sqrt(2.0))) for e in edges]
    return np.diff([0.0, *cdf, 1.0])


def noisy_depth(
    z_m: NDArray[np.floating],
    model: KinectConfig,
    rng: np.random.Generator,
    out: NDArray[np.float32] | None = None,
) -> NDArray[np.float32]:
    """Perfect depth (m, 0 = nothing) → what a Kinect v1 would report (float32, 0 = invalid),
    written into ``out`` when given (a camera frame's ring slot, say; not ``z_m``'s memory)."""
    z = np.ascontiguousarray(z_m, dtype=np.float32)
    h, w = z.shape
    out = _output(out, z, np.float32)
    lateral = model.lateral_noise_px > 0
    if not _two_bands(h, h * w):
        pieces = [(0, _uniform_u16(rng, h * w))] if lateral else []
        _noisy_band(z, pieces, _uniform_u16(rng, _even(h * w)), (0, h), out, model)
        return out
    # Two bands of rows. The invalid band along edges needs the displaced depth a few rows
    # beyond a band, so the lateral uniforms of the rows around the middle are drawn first,
    # for both; each band then draws the rest from its own stream.
    mid = h // 2
    halo = 1 + model.edge_dropout_px
    lo, hi = max(0, mid - halo), min(h, mid + halo)
    seed = rng.bit_generator.random_raw(2)
    shared = (lo, _uniform_u16(rng, (hi - lo) * w))

    def lower_band() -> None:
        child = np.random.Generator(np.random.PCG64(seed))
        pieces = [shared, (hi, _uniform_u16(child, (h - hi) * w))] if lateral else []
        axial = _uniform_u16(child, _even((h - mid) * w))
        _noisy_band(z, pieces, axial, (mid, h), out, model)

    pending = _on_helper(lower_band)
    try:
        pieces = [(0, _uniform_u16(rng, lo * w)), shared] if lateral else []
        _noisy_band(z, pieces, _uniform_u16(rng, _even(mid * w)), (0, mid), out, model)
    finally:
        _join(pending, lower_band)
    return out


def exposed_rgb(
    rgb: NDArray[np.uint8],
    model: KinectConfig,
    rng: np.random.Generator,
    out: NDArray[np.uint8] | None = None,
) -> NDArray[np.uint8]:
    """Exposure, colour temperature and sensor noise on a perfect RGB image:
    ``clip(rint(gain_c·rgb + N(0, rgb_noise_sigma)), 0, 255)`` per channel, ties to even;
    written into ``out`` when given (not ``rgb``'s memory)."""
    image = np.ascontiguousarray(rgb, dtype=np.uint8)
    out = _output(out, image, np.uint8)
    t = model.colour_temperature
    gains = (
        model.brightness * (1.0 - 0.25 * t),
        model.brightness,
        model.brightness * (1.0 + 0.25 * t),
        0.0,
    )
    if model.rgb_noise_sigma <= 0:
        return cv2.multiply(image, gains, dst=out)  # rounds to nearest (ties to even), saturates
    per_channel = gains[0] != gains[2] and image.ndim == 3 and image.shape[2] == 3
    h = image.shape[0]

    def band(rows: tuple[int, int], stream: np.random.Generator) -> None:
        src = image[rows[0] : rows[1]].reshape(-1)
        dst = out[rows[0] : rows[1]].reshape(-1)
        size = src.size
        noise = _scratch("rgb_noise", (_even(size),), np.float32)
        _box_muller(_uniform_u16(stream, noise.size), noise)
        noise = noise[:size]
        sigma = model.rgb_noise_sigma
        if not per_channel:
            cv2.addWeighted(src, gains[1], noise, sigma, 0.0, dtype=cv2.CV_8U, dst=dst)
            return
        shape = (1, size // 3, 3)  # whole pixels: one 3-channel row, per-channel gains
        scaled = cv2.multiply(
            src.reshape(shape), gains, dtype=cv2.CV_32F, dst=_scratch("rgb_gain", shape, np.float32)
        )
        cv2.addWeighted(
            scaled, 1.0, noise.reshape(shape), sigma, 0.0, dtype=cv2.CV_8U, dst=dst.reshape(shape)
        )

    if not _two_bands(h, image.size):
        band((0, h), rng)
        return out
    seed = rng.bit_generator.random_raw(2)

    def lower_band() -> None:
        band((h // 2, h), np.random.Generator(np.random.PCG64(seed)))

    pending = _on_helper(lower_band)
    try:
        band((0, h // 2), rng)
    finally:
        _join(pending, lower_band)
    return out


# --- internals ------------------------------------------------------------------------------


def _noisy_band(
    z: NDArray[np.float32],
    pieces: list[tuple[int, NDArray[np.uint16]]],
    axial: NDArray[np.uint16],
    rows: tuple[int, int],
    out: NDArray[np.float32],
    model: KinectConfig,
) -> None:
    """``noisy_depth`` for rows [r0, r1) of ``out``. The invalid band along edges needs the
    displaced depth of ``1 + edge_dropout_px`` rows beyond them (computed again here: same
    offsets, same values), the rest is per pixel. ``pieces`` are the lateral uniforms of these
    rows, (first row, uniforms), empty without lateral noise; ``axial`` the axial ones."""
    h, w = z.shape
    r0, r1 = rows
    halo = 1 + model.edge_dropout_px
    e0, e1 = max(0, r0 - halo), min(h, r1 + halo)
    core = slice(r0 - e0, r1 - e0)
    if pieces:
        # One int32 per pixel = the (du, dv) int16 pair, added to the pixel grid: a CV_16SC2
        # map. BORDER_REPLICATE clamps displaced coordinates to the image, as np.clip did.
        offsets = _scratch("offsets", (e1 - e0, w, 2), np.int16)
        table = _lateral_table(float(model.lateral_noise_px))
        for first_row, uniforms in pieces:
            block = offsets[first_row - e0 : first_row - e0 + uniforms.size // w]
            np.take(table, uniforms, out=block.view(np.int32).reshape(-1), mode="clip")
        np.add(offsets, _pixel_grid(h, w)[e0:e1], out=offsets)
        zd = cv2.remap(
            z,
            offsets,
            None,
            cv2.INTER_NEAREST,
            dst=_scratch("displaced", (e1 - e0, w), np.float32),
            borderMode=cv2.BORDER_REPLICATE,
        )
    else:
        zd = z[e0:e1]
    edges = _edge_mask_u8(zd, model.edge_threshold_m, model.edge_dropout_px)[core]
    zc = zd[core]
    shape = zc.shape
    invalid = cv2.inRange(
        zc, model.min_range_m, model.max_range_m, dst=_scratch("invalid", shape, np.uint8)
    )
    cv2.compare(invalid, edges, cv2.CMP_LE, dst=invalid)  # out of range, or near an edge

    # z + σ_z(z)·N(0, 1) with σ_z = a + (√b·(z − z0))², 0 where invalid, quantised.
    normals = _scratch("axial_normals", (axial.size,), np.float32)
    _box_muller(axial, normals)
    normals = normals[: zc.size].reshape(shape)
    root_b = math.sqrt(AXIAL_SIGMA_QUAD)
    spread = cv2.addWeighted(
        zc, root_b, zc, 0.0, -root_b * AXIAL_SIGMA_Z0_M, dst=_scratch("spread", shape, np.float32)
    )
    sigma = _scratch("sigma", shape, np.float32)
    sigma.fill(AXIAL_SIGMA_0_M)
    cv2.accumulateSquare(spread, sigma)
    target = out[r0:r1]
    if pieces:
        noisy = zc  # the displaced depth, ours to overwrite
    else:
        noisy = target
        np.copyto(noisy, zc)
    cv2.accumulateProduct(sigma, normals, noisy)
    cv2.subtract(noisy, noisy, dst=noisy, mask=invalid)
    if not model.quantise:
        if noisy is not target:
            np.copyto(target, noisy)
        return
    # quantise_depth in float32; invalid depths are 0 here: S/0 = inf, rint(inf) = inf and
    # S/inf = 0 again.
    scale = np.float32(DISPARITY_SCALE_M)
    if model.min_range_m < 0.01:  # z − 4.85·σ_z(z) can reach 0 below 1 cm: keep 0 there
        np.maximum(noisy, 0.0, out=noisy)
    with np.errstate(divide="ignore"):
        np.divide(scale, noisy, out=target)
    np.rint(target, out=target)
    if model.max_range_m > 100.0:  # beyond, z + 4.85·σ_z(z) can pass 2S: 0 steps become 1
        np.maximum(target, 1.0, out=target)
    np.divide(scale, target, out=target)


def _output(out: np.ndarray | None, image: np.ndarray, dtype: type) -> np.ndarray:
    """``out`` checked to take a model's output of ``image`` (its shape, ``dtype``,
    C-contiguous, not sharing its memory: the model reads pixels it has already written), or a
    fresh array."""
    if out is None:
        return np.empty(image.shape, dtype)
    if out.shape != image.shape or out.dtype != dtype or not out.flags.c_contiguous:
        raise ValueError(f"cannot write a {np.dtype(dtype)} {image.shape} image into {out.shape}")
    if np.shares_memory(out, image):
        raise ValueError("the sensor model cannot write over its own input")
    return out


def _even(n: int) -> int:
    return n + n % 2


def _two_bands(rows: int, values: int) -> bool:
    return rows >= 64 and values >= _SPLIT_MIN


def _on_helper(work: Callable[[], None]) -> Future[None] | None:
    """``work`` started on the helper thread (None when disabled: ``_join`` then does it)."""
    if not _helper_enabled:
        return None
    global _helper
    with _helper_lock:
        if _helper is None:
            _helper = ThreadPoolExecutor(max_workers=1, thread_name_prefix="kinect-model")
    return _helper.submit(work)


def _join(pending: Future[None] | None, work: Callable[[], None]) -> None:
    """Wait for ``work`` on the helper thread, or do it now if it was not handed over."""
    if pending is None:
        work()
    else:
        pending.result()


def _uniform_u16(rng: np.random.Generator, count: int) -> NDArray[np.uint16]:
    """``count`` independent uniform uint16 from the generator's raw 64-bit output."""
    words = rng.bit_generator.random_raw((count + 3) // 4)
    return words.view(np.uint16)[:count]


def _box_muller(uniforms: NDArray[np.uint16], out: NDArray[np.float32]) -> None:
    """N(0, 1) float32 samples into ``out`` from as many uint16 uniforms (an even count):
    the first half gives the radii, the second the angles. Float32 all the way, with a
    relative error of 1e-7 (no cancellation: ln u1 of u1 itself)."""
    m = uniforms.size // 2
    buffer = _scratch("box_muller", (2 * m,), np.float32)
    u1, u2 = uniforms[:m], uniforms[m : 2 * m]
    radius = cv2.addWeighted(
        u1, 1.0 / _U16, u1, 0.0, 0.5 / _U16, dtype=cv2.CV_32F, dst=buffer[:m]
    )  # (k + 0.5)/65536
    cv2.log(radius, dst=radius)
    cv2.addWeighted(radius, -2.0, radius, 0.0, 0.0, dst=radius)
    cv2.sqrt(radius, dst=radius)
    angle = cv2.addWeighted(
        u2, 2.0 * math.pi / _U16, u2, 0.0, math.pi / _U16, dtype=cv2.CV_32F, dst=buffer[m : 2 * m]
    )
    cv2.polarToCart(radius, angle, x=out[:m], y=out[m:])


def _scratch(tag: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """A per-thread buffer kept between calls (fresh pages cost as much as the work)."""
    cache: dict | None = getattr(_local, "buffers", None)
    if cache is None:
        cache = _local.buffers = {}
    key = (tag, shape, np.dtype(dtype).str)
    buf = cache.get(key)
    if buf is None:
        if len(cache) > 64:  # many image sizes: start again rather than grow
            cache.clear()
        buf = cache[key] = np.empty(shape, dtype)
    return buf


@lru_cache(maxsize=16)
def _pixel_grid(h: int, w: int) -> NDArray[np.int16]:
    grid = np.empty((h, w, 2), np.int16)
    grid[..., 0] = np.arange(w, dtype=np.int16)[None, :]
    grid[..., 1] = np.arange(h, dtype=np.int16)[:, None]
    grid.setflags(write=False)
    return grid


@lru_cache(maxsize=16)
def _lateral_table(sigma_px: float) -> NDArray[np.int32]:
    """65536 entries, each an int16 (du, dv) pair read as one int32; outcome (du, dv) fills
    round(65536·P(du)·P(dv)) entries (largest remainders, so that they add up to 65536)."""
    p = lateral_offset_probabilities(sigma_px)
    expected = np.outer(p, p).ravel() * _U16  # index (dv + 2)·5 + (du + 2)
    counts = np.floor(expected).astype(np.int64)
    remainder = expected - counts
    counts[np.argsort(-remainder, kind="stable")[: _U16 - int(counts.sum())]] += 1
    d = np.arange(-LATERAL_CLIP_PX, LATERAL_CLIP_PX + 1, dtype=np.int16)
    pairs = np.stack([np.tile(d, d.size), np.repeat(d, d.size)], axis=1)  # (du, dv)
    table = np.repeat(np.ascontiguousarray(pairs).view(np.int32).ravel(), counts)
    table.setflags(write=False)
    return table


def _edge_mask_u8(z: NDArray[np.float32], threshold_m: float, band_px: int) -> NDArray[np.uint8]:
    """``edge_mask`` as 0/255 in a scratch buffer. The test is max > min + threshold, which
    float32 rounding can decide differently from max − min > threshold only when the jump is
    within 1e-7 m of the threshold."""
    h, w = z.shape
    local_max = cv2.dilate(z, _KERNEL_3X3, dst=_scratch("edge_max", (h, w), np.float32))
    # Holes (0) must not lower the minimum: +inf there. The threshold is added before taking
    # the minimum, so that a jump is max > min + threshold (a pass less than max − min > t).
    holes = cv2.threshold(
        z, 0.0, np.inf, cv2.THRESH_BINARY_INV, dst=_scratch("edge_raised", (h, w), np.float32)
    )[1]
    raised = cv2.addWeighted(z, 1.0, holes, 1.0, threshold_m, dst=holes)
    local_min = cv2.erode(raised, _KERNEL_3X3, dst=_scratch("edge_min", (h, w), np.float32))
    jumps = cv2.compare(
        local_max, local_min, cv2.CMP_GT, dst=_scratch("edge_jumps", (h, w), np.uint8)
    )
    if band_px > 0:
        band = np.ones((2 * band_px + 1, 2 * band_px + 1), np.uint8)
        jumps = cv2.dilate(jumps, band, dst=_scratch("edge_band", (h, w), np.uint8))
    return jumps
