"""``umay accuracy``: how well vision measures the markers, against the simulator's truth.

For postures sampled around each scenario's start-to-goal motion, the scene is rendered once
(perfect images) and then seen under each sensor condition: perfect, the Kinect v1 model,
brighter and darker exposure, HSV or RGB segmentation, depth at 320×240. Each condition's
frames go through the vision core (:func:`services.vision.measurement.measure_markers`) and are
compared with the projected true corners and their true depths.

Postures where both markers are wholly in view, with no other part of the robot touching their
outline (a segmentation render says so), measure accuracy; postures where the hand hides part
of the target measure whether vision refuses the partly hidden square (it must: its corners
would be wrong).

Ground truth is used here to judge vision, never fed to it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel

from common import kinematics as kin
from common.camera import CameraIntrinsics
from common.config import KinectConfig, Scenario, VisionConfig
from common.marker import Marker
from deploy.launch.reachability import check_scenario
from services.sim.sensor_model import axial_sigma_m, exposed_rgb, noisy_depth
from services.sim.world import World
from services.vision.measurement import measure_markers

MARKER_POSES = {"hand": "hand_marker_pose", "target": "target_marker_pose"}
POSTURE_NOISE_RAD = 0.08  # joint-space spread around the start-to-goal motion
WHOLE = 0.999  # a marker is wholly in view when this fraction of its square shows it
PARTLY = (0.1, 0.95)  # ... and partly hidden between these
MAX_TRIES = 30  # postures drawn per posture kept, before giving up on a scenario
# Reasons of a marker whose square colour segmentation did find (depth refused it).
SEEN_IN_COLOUR = ("", "no valid depth", "occluded")


@dataclass(frozen=True)
class Condition:
    """One way of seeing the same scene."""

    name: str
    kinect: KinectConfig
    vision: VisionConfig
    depth_size_px: tuple[int, int] | None = None  # (width, height) when not the colour size


def default_conditions(seed: int = 0) -> list[Condition]:
    ideal = KinectConfig(enabled=False, seed=seed)
    kinect = KinectConfig(enabled=True, seed=seed)
    hsv, rgb = VisionConfig(segmentation="hsv"), VisionConfig(segmentation="rgb")
    out = [Condition("perfect images, HSV", ideal, hsv), Condition("Kinect, HSV", kinect, hsv)]
    for brightness in (0.5, 1.5):
        lit = kinect.model_copy(update={"brightness": brightness})
        out.append(Condition(f"Kinect, brightness {brightness}x, HSV", lit, hsv))
    out.append(Condition("Kinect, RGB", kinect, rgb))
    for brightness in (0.5, 1.5):
        lit = kinect.model_copy(update={"brightness": brightness})
        out.append(Condition(f"Kinect, brightness {brightness}x, RGB", lit, rgb))
    out.append(Condition("Kinect, depth 320x240, HSV", kinect, hsv, (320, 240)))
    return out


class ConditionResult(BaseModel):
    """Accuracy of vision under one condition (corner errors over found markers only)."""

    condition: str
    frames: int
    seen_both_fraction: float  # frames in which colour segmentation found both squares
    found_both_fraction: float  # ... and vision reported both usable (depth and checks too)
    found: dict[str, float]  # per marker, fraction of frames usable
    corner_rms_px: float | None
    corner_max_px: float | None
    depth_rms_m: float | None
    depth_max_m: float | None
    within_2_sigma_z: float | None  # fraction of corner depths within 2·σ_z(z) of the truth
    within_2_reported_sigma: float | None  # ... within 2× vision's own per-corner 1-σ
    median_reported_sigma_m: float | None
    reasons: dict[str, int] = {}  # why markers were not found, counted
    partly_hidden_frames: int = 0  # postures with the target partly hidden by the hand
    partly_hidden_refused: float | None = None  # ... in which vision did not report it visible


@dataclass
class _Tally:
    frames: int = 0
    both_seen: int = 0
    both: int = 0
    found: dict[str, int] = field(default_factory=lambda: dict.fromkeys(MARKER_POSES, 0))
    corner_err_px: list[float] = field(default_factory=list)
    depth_err_m: list[float] = field(default_factory=list)
    sigma_z_m: list[float] = field(default_factory=list)
    reported_sigma_m: list[float] = field(default_factory=list)
    reasons: dict[str, int] = field(default_factory=dict)
    partly_hidden: int = 0
    refused: int = 0

    def result(self, name: str) -> ConditionResult:
        c = np.array(self.corner_err_px)
        d = np.abs(np.array(self.depth_err_m))
        sz, rs = np.array(self.sigma_z_m), np.array(self.reported_sigma_m)
        n = max(self.frames, 1)
        return ConditionResult(
            condition=name,
            frames=self.frames,
            seen_both_fraction=self.both_seen / n,
            found_both_fraction=self.both / n,
            found={k: v / n for k, v in self.found.items()},
            corner_rms_px=float(np.sqrt(np.mean(c**2))) if c.size else None,
            corner_max_px=float(np.max(c)) if c.size else None,
            depth_rms_m=float(np.sqrt(np.mean(d**2))) if d.size else None,
            depth_max_m=float(np.max(d)) if d.size else None,
            within_2_sigma_z=float(np.mean(d <= 2 * sz)) if d.size else None,
            within_2_reported_sigma=float(np.mean(d <= 2 * rs)) if d.size else None,
            median_reported_sigma_m=float(np.median(rs)) if rs.size else None,
            reasons=dict(sorted(self.reasons.items())),
            partly_hidden_frames=self.partly_hidden,
            partly_hidden_refused=self.refused / self.partly_hidden if self.partly_hidden else None,
        )


def match_corners(measured_px: np.ndarray, true_px: np.ndarray) -> np.ndarray:
    """Index of the true corner for each measured one: the cyclic order (either direction)
    that fits best, as vision labels corners by their place in the image."""
    best, best_cost = None, math.inf
    for order in (np.arange(4), np.arange(4)[::-1]):
        for shift in range(4):
            index = np.roll(order, shift)
            cost = float(np.sum((measured_px - true_px[index]) ** 2))
            if cost < best_cost:
                best, best_cost = index, cost
    assert best is not None
    return best


def sample_postures(scenario: Scenario, n: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Joint configurations along the start-to-goal motion, spread a little around it, kept
    inside the joint limits."""
    q0 = np.array(scenario.robot.q0)
    goal = check_scenario(scenario)
    out = []
    for _ in range(n):
        q = q0 + rng.uniform(0.0, 1.0) * (goal - q0) + rng.normal(0.0, POSTURE_NOISE_RAD, 6)
        out.append(np.clip(q, kin.JOINT_LOWER_RAD, kin.JOINT_UPPER_RAD))
    return out


def _true_depths_m(world: World, pose_in_base: np.ndarray, size_m: float) -> np.ndarray:
    corners = kin.marker_corners(pose_in_base, size_m)
    cam = np.linalg.inv(world.camera_pose) @ np.column_stack([corners, np.ones(4)]).T
    return cam[2]


def _score(
    tally: _Tally,
    measured: dict[str, Marker],
    truth_px: dict[str, np.ndarray],
    truth_z: dict[str, np.ndarray],
) -> None:
    tally.frames += 1
    tally.both_seen += all(m.reason in SEEN_IN_COLOUR for m in measured.values())
    tally.both += all(m.visible for m in measured.values())
    for name, m in measured.items():
        if not m.visible:
            tally.reasons[f"{name}: {m.reason}"] = tally.reasons.get(f"{name}: {m.reason}", 0) + 1
            continue
        tally.found[name] += 1
        index = match_corners(m.corners_px, truth_px[name])
        tally.corner_err_px += np.linalg.norm(m.corners_px - truth_px[name][index], axis=1).tolist()
        z = truth_z[name][index]
        tally.depth_err_m += (m.depth_m - z).tolist()
        tally.sigma_z_m += axial_sigma_m(z).tolist()
        tally.reported_sigma_m += m.depth_sigma_m.tolist()


def evaluate(
    scenarios: list[Scenario],
    frames_per_scenario: int,
    conditions: list[Condition],
    seed: int = 0,
    progress=None,
) -> list[ConditionResult]:
    """Vision accuracy per condition over ``frames_per_scenario`` postures of every scenario
    with both markers wholly in view (plus the partly hidden ones met on the way).
    ``progress(done, total)`` is called after each posture kept."""
    tallies = {c.name: _Tally() for c in conditions}
    rng = np.random.default_rng(seed)
    total = frames_per_scenario * len(scenarios)
    done = 0
    for scenario in scenarios:
        world = World(scenario)
        sensor_rng = np.random.default_rng(seed)
        kept = 0
        try:
            for q in sample_postures(scenario, MAX_TRIES * frames_per_scenario, rng):
                if kept == frames_per_scenario:
                    break
                world.reset(q)
                world.update_scene()
                seen = world.marker_visibility()
                hand_whole = seen["hand"].fraction >= WHOLE and not seen["hand"].touched
                whole = hand_whole and seen["target"].fraction >= WHOLE
                whole = whole and not seen["target"].touched
                partly = hand_whole and PARTLY[0] <= seen["target"].fraction <= PARTLY[1]
                if not (whole or partly):
                    continue
                measured = _observe_posture(world, scenario, conditions, sensor_rng)
                truth = _truth(world, scenario)
                for c in conditions:
                    if whole:
                        _score(tallies[c.name], measured[c.name], *truth)
                    else:
                        tallies[c.name].partly_hidden += 1
                        tallies[c.name].refused += not measured[c.name]["target"].visible
                if whole:
                    kept += 1
                    done += 1
                    if progress is not None:
                        progress(done, total)
        finally:
            world.close()
    return [tallies[c.name].result(c.name) for c in conditions]


def _truth(world: World, scenario: Scenario) -> tuple[dict, dict]:
    """True corners (px, physical order) and their depths (m) of both markers."""
    truth = world.truth()
    size = scenario.marker.size_m
    truth_px = {"hand": truth.hand_corners_px, "target": truth.target_corners_px}
    truth_z = {
        "hand": _true_depths_m(world, truth.hand_marker_pose, size),
        "target": _true_depths_m(world, truth.target_marker_pose, size),
    }
    return truth_px, truth_z


def _observe_posture(
    world: World,
    scenario: Scenario,
    conditions: list[Condition],
    rng: np.random.Generator,
) -> dict[str, dict[str, Marker]]:
    """What vision makes of the current posture under each condition."""
    k = world.intrinsics
    rgb, depth = world.render_perfect(k)
    small: dict[tuple[int, int], tuple[CameraIntrinsics, np.ndarray]] = {}
    out = {}
    for c in conditions:
        k_depth, perfect_depth = None, depth
        if c.depth_size_px is not None:
            if c.depth_size_px not in small:
                k_small = CameraIntrinsics.from_fov(*c.depth_size_px, scenario.camera.hfov_deg)
                small[c.depth_size_px] = (k_small, world.render_perfect(k_small)[1])
            k_depth, perfect_depth = small[c.depth_size_px]
        seen_rgb, seen_depth = rgb, perfect_depth
        if c.kinect.enabled:
            seen_rgb = exposed_rgb(rgb, c.kinect, rng)
            seen_depth = noisy_depth(perfect_depth, c.kinect, rng)
        out[c.name] = measure_markers(
            seen_rgb,
            seen_depth,
            k,
            c.vision,
            k_depth=k_depth,
            orientation_cue=scenario.marker.orientation_cue,
        )
    return out


def format_table(results: list[ConditionResult]) -> str:
    def f(v: float | None, fmt: str, scale: float = 1.0) -> str:
        return "-" if v is None else format(v * scale, fmt)

    lines = [
        f"{'condition':36s} {'frames':>6s} {'both seen':>9s} {'both used':>9s} "
        f"{'corner RMS':>10s} {'max':>6s} {'depth RMS':>9s} {'max':>7s} {'≤2σz':>6s} "
        f"{'own σ':>6s} {'≤2σ own':>7s}",
        f"{'':36s} {'':>6s} {'':>9s} {'':>9s} {'px':>10s} {'px':>6s} {'mm':>9s} {'mm':>7s} "
        f"{'':>6s} {'mm':>6s}",
    ]
    for r in results:
        lines.append(
            f"{r.condition:36s} {r.frames:6d} {100 * r.seen_both_fraction:8.1f}% "
            f"{100 * r.found_both_fraction:8.1f}% "
            f"{f(r.corner_rms_px, '.3f'):>10s} {f(r.corner_max_px, '.2f'):>6s} "
            f"{f(r.depth_rms_m, '.3f', 1e3):>9s} {f(r.depth_max_m, '.2f', 1e3):>7s} "
            f"{f(r.within_2_sigma_z, '.1%'):>6s} {f(r.median_reported_sigma_m, '.3f', 1e3):>6s} "
            f"{f(r.within_2_reported_sigma, '.1%'):>7s}"
        )
        if r.reasons:
            lines.append(
                f"{'':38s}not found: " + ", ".join(f"{k} ×{v}" for k, v in r.reasons.items())
            )
    return "\n".join(lines)
