"""``sim.renderer``: TinyRenderer stays the default; the EGL plugin, where it loads, renders the
same geometry (depth to a fraction of a millimetre, markers found at the same corners)."""

from __future__ import annotations

import numpy as np
import pytest

from common.config import load_scenario
from common.runtime import parse_overrides
from services.sim.world import (
    FLOOR_COLOUR,
    TABLE_COLOUR,
    RendererError,
    World,
    opengl_projection_matrix,
)
from services.vision.tracking import DepthImage, TrackerState, observe

SIZE = ["camera.width_px=320", "camera.height_px=240"]


def test_tinyrenderer_is_the_default_and_its_projection_is_unchanged() -> None:
    scenario = load_scenario()
    assert scenario.sim.renderer == "tiny"
    k = scenario.camera.intrinsics()
    p = np.array(opengl_projection_matrix(k, 0.05, 5.0)).reshape(4, 4, order="F")
    assert p[0, 2] == pytest.approx(-(2.0 * k.cx_px / k.width_px - 1.0))
    assert p[1, 2] == pytest.approx(2.0 * (k.cy_px + 1.0) / k.height_px - 1.0)
    egl = np.array(opengl_projection_matrix(k, 0.05, 5.0, "egl")).reshape(4, 4, order="F")
    assert egl[0, 2] == pytest.approx(-(2.0 * (k.cx_px + 0.5) / k.width_px - 1.0))


def test_the_table_then_the_floor_are_made_last_so_tinyrenderer_draws_them_last() -> None:
    """TinyRenderer draws bodies in the order they were made and shades whatever passes the
    depth test when drawn: the floor drawn before the table and the arm is shaded where they
    hide it, 36 ms more a 640×480 frame (README, Performance). Images are the same either way."""
    world = World(load_scenario())
    try:
        c = world.client
        colours = [tuple(c.getVisualShapeData(b)[0][7]) for b in range(c.getNumBodies())]
    finally:
        world.close()
    assert colours[-2:] == [pytest.approx(TABLE_COLOUR), pytest.approx(FLOOR_COLOUR)]
    assert colours[0] != pytest.approx(FLOOR_COLOUR)  # body 0, the robot, is drawn first


def render_and_measure(renderer: str) -> tuple[np.ndarray, dict]:
    scenario = load_scenario(None, parse_overrides([*SIZE, f"sim.renderer='{renderer}'"]))
    world = World(scenario)
    try:
        rgb, depth = world.render()
    finally:
        world.close()
    k = scenario.camera.intrinsics()
    measured, _ = observe(
        rgb, k, DepthImage(depth, k, 0.0), scenario.vision, scenario.marker.size_m, TrackerState()
    )
    return depth, measured


def test_egl_renders_the_same_geometry_as_tinyrenderer() -> None:
    try:
        depth_egl, egl = render_and_measure("egl")
    except RendererError as exc:  # no libEGL on this machine
        pytest.skip(str(exc))
    depth_tiny, tiny = render_and_measure("tiny")
    both = (depth_tiny > 0) & (depth_egl > 0)
    assert both.mean() > 0.99
    assert np.median(np.abs(depth_tiny[both] - depth_egl[both])) < 2e-4  # m
    for name in ("hand", "target"):
        assert tiny[name].state == egl[name].state == "visible", name
        np.testing.assert_allclose(egl[name].corners_px, tiny[name].corners_px, atol=0.2)
        np.testing.assert_allclose(egl[name].depths_m, tiny[name].depths_m, atol=5e-4)
