"""Rendering into given arrays (the frame ring's slots): OpenGL draws the very images it would
draw into fresh arrays, into the arrays given, at the colour and the depth resolution;
TinyRenderer leaves them alone; with the Kinect model on, the model writes its images there
(either renderer); an array that does not fit is refused, never overrun."""

from __future__ import annotations

import numpy as np
import pytest

from common.config import load_scenario
from common.runtime import parse_overrides
from services.sim.world import World

SIZE = ["camera.width_px=320", "camera.height_px=240"]


def world(*overrides: str) -> World:
    w = World(load_scenario(overrides=parse_overrides([*SIZE, *overrides])))
    if w.renderer != "gl" and "sim.renderer='tiny'" not in overrides:
        w.close()
        pytest.fail(f"no OpenGL renderer on this machine: {w.renderer_detail}")
    return w


def slots(w: World) -> tuple[np.ndarray, np.ndarray]:
    k, kd = w.intrinsics, w.depth_intrinsics
    return (
        np.full((k.height_px, k.width_px, 3), 7, np.uint8),
        np.full((kd.height_px, kd.width_px), -1.0, np.float32),
    )


@pytest.mark.parametrize(
    "overrides", [(), ("camera.depth_width_px=160", "camera.depth_height_px=120")]
)
def test_opengl_draws_the_same_images_into_the_arrays_given(overrides: tuple[str, ...]) -> None:
    w = world(*overrides)
    try:
        assert (w.depth_intrinsics != w.intrinsics) == bool(overrides)  # the split, if asked
        fresh_rgb, fresh_depth = w.render(True)
        out = slots(w)
        rgb, depth_m = w.render(True, out)
        assert rgb is out[0] and depth_m is out[1]  # drawn there: nothing to copy
        np.testing.assert_array_equal(rgb, fresh_rgb)
        np.testing.assert_array_equal(depth_m, fresh_depth)
        assert depth_m.shape == (w.depth_intrinsics.height_px, w.depth_intrinsics.width_px)
        # Colour alone (no depth image due): the depth array is not touched.
        out = slots(w)
        rgb, depth_m = w.render(False, (out[0], None))
        assert rgb is out[0] and depth_m is None
        np.testing.assert_array_equal(rgb, fresh_rgb)
    finally:
        w.close()


@pytest.mark.parametrize("renderer", ["gl", "tiny"])
@pytest.mark.parametrize(
    "overrides", [(), ("camera.depth_width_px=160", "camera.depth_height_px=120")]
)
def test_the_kinect_model_writes_its_images_into_the_arrays_given(
    overrides: tuple[str, ...], renderer: str
) -> None:
    """What the camera reports goes straight into the arrays given (a ring slot: nothing to
    copy into it), the same images as into fresh arrays from the same seed."""
    kinect = ("camera.kinect.enabled=true", f"sim.renderer='{renderer}'", *overrides)
    fresh_world, slot_world = world(*kinect), world(*kinect)
    try:
        for with_depth in (True, False, True):
            fresh_rgb, fresh_depth = fresh_world.render(with_depth)
            out = slots(slot_world)
            rgb, depth_m = slot_world.render(with_depth, (out[0], out[1] if with_depth else None))
            assert rgb is out[0]
            np.testing.assert_array_equal(rgb, fresh_rgb)
            if with_depth:
                assert depth_m is out[1]
                np.testing.assert_array_equal(depth_m, fresh_depth)
            else:
                assert depth_m is None and fresh_depth is None and np.all(out[1] == -1.0)
    finally:
        fresh_world.close()
        slot_world.close()


def test_an_array_that_does_not_fit_is_refused() -> None:
    w = world()
    try:
        rgb_out, depth_out = slots(w)
        with pytest.raises(ValueError, match="cannot read"):
            w.render(True, (rgb_out[:, :-1], depth_out))  # not contiguous, one column short
        with pytest.raises(ValueError, match="cannot read"):
            w.render(True, (rgb_out, depth_out.astype(np.float64)))
    finally:
        w.close()


def test_tinyrenderer_leaves_the_arrays_alone() -> None:
    w = world("sim.renderer='tiny'")
    try:
        out = slots(w)
        rgb, depth_m = w.render(True, out)
        assert rgb is not out[0] and depth_m is not out[1]
        assert np.all(out[0] == 7) and np.all(out[1] == -1.0)
        assert rgb.shape == out[0].shape and depth_m is not None and depth_m.max() > 0
    finally:
        w.close()
