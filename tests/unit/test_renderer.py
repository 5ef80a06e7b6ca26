"""``sim.renderer``: the OpenGL renderer (the default) against the analytic geometry, against
pybullet's TinyRenderer (the reference) and against pybullet's segmentation; the fallback to
TinyRenderer where no OpenGL context can be made."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from common.config import Scenario, load_scenario
from common.runtime import parse_overrides
from deploy.experiments.accuracy import WHOLE, sample_postures
from services.sim import renderers
from services.sim.gl_renderer import GlUnavailable, depth_uniforms, pinhole_uniforms
from services.sim.projection import opengl_projection_matrix
from services.sim.shapes import box_mesh, cylinder_mesh
from services.sim.urdf import TABLE_TOP_Y_M
from services.sim.world import FLOOR_TOP_Y_M, World
from services.vision.measurement import measure_markers

SIZE = ["camera.width_px=320", "camera.height_px=240"]
TINY = ["sim.renderer='tiny'"]


def test_gl_is_the_default_and_tinyrenderer_projection_is_unchanged() -> None:
    scenario = load_scenario()
    assert scenario.sim.renderer == "gl"
    k = scenario.camera.intrinsics()
    p = np.array(opengl_projection_matrix(k, 0.05, 5.0)).reshape(4, 4, order="F")
    assert p[0, 2] == pytest.approx(-(2.0 * k.cx_px / k.width_px - 1.0))
    assert p[1, 2] == pytest.approx(2.0 * (k.cy_px + 1.0) / k.height_px - 1.0)


def test_pinhole_uniforms_put_pixel_centres_on_the_pinhole_model() -> None:
    k = load_scenario().camera.intrinsics()
    a, b, c, d = pinhole_uniforms(k)
    for u, v in ((0, 0), (k.cx_px, k.cy_px), (k.width_px - 1, k.height_px - 1)):
        x, y = (u - k.cx_px) / k.fx_px, (v - k.cy_px) / k.fy_px
        # OpenGL samples pixel j at window x = j + 0.5, x_ndc = 2·x_w/W − 1.
        assert (a * x + b + 1) / 2 * k.width_px == pytest.approx(u + 0.5)
        assert (c * y + d + 1) / 2 * k.height_px == pytest.approx(v + 0.5)
    big_a, big_b = depth_uniforms(0.05, 5.0)
    assert big_a + big_b / 0.05 == pytest.approx(-1.0) and big_a + big_b / 5.0 == pytest.approx(1)


def test_meshes_are_closed_with_outward_normals_at_the_true_size() -> None:
    vertices, normals = box_mesh((0.2, 0.4, 0.6))
    assert vertices.shape == normals.shape == (36, 3)
    np.testing.assert_allclose(np.abs(vertices).max(axis=0), [0.1, 0.2, 0.3], rtol=1e-6)
    assert np.all(np.sum(vertices * normals, axis=1) > 0)  # outward
    vertices, normals = cylinder_mesh(0.264, 0.022)
    side = normals[:, 2] == 0
    np.testing.assert_allclose(np.hypot(*vertices[side, :2].T), 0.022, rtol=1e-6)
    np.testing.assert_allclose(np.abs(vertices[:, 2]).max(), 0.132, rtol=1e-6)
    assert np.all(np.sum(vertices * normals, axis=1) > 0)


@pytest.fixture(scope="module")
def gl_world():
    w = World(load_scenario())
    if w.renderer != "gl":
        w.close()
        pytest.fail(f"no OpenGL renderer on this machine: {w.renderer_detail}")
    yield w
    w.close()


def ray_hits(
    scenario: Scenario, rows: np.ndarray, cols: np.ndarray, face: tuple
) -> tuple[np.ndarray, np.ndarray]:
    """Z along the optical axis where pixel rays meet the plane of a rectangular ``face``
    (centre, unit normal, two unit in-plane axes, half extents along them), and whether the
    hit lies inside the face with a 2 mm margin."""
    centre, normal, axes, half = face
    k, pose = scenario.camera.intrinsics(), scenario.camera.pose()
    rays = np.stack([(cols - k.cx_px) / k.fx_px, (rows - k.cy_px) / k.fy_px, np.ones(len(rows))])
    rays_world = pose[:3, :3] @ rays  # unit optical-axis component: the factor is Z
    z = (normal @ (centre - pose[:3, 3])) / (normal @ rays_world)
    hits = pose[:3, 3, None] + rays_world * z
    inside = np.ones(len(rows), bool)
    for axis, h in zip(axes, half, strict=True):
        inside &= np.abs(axis @ (hits - centre[:, None])) < h - 0.002
    return z, inside


def test_gl_depth_is_the_analytic_geometry(gl_world: World) -> None:
    """Table top, floor and the red marker's face: every pixel within 1e-6 m of the ray's hit."""
    ids = gl_world.segmentation(gl_world.intrinsics)
    _, depth = gl_world.render_perfect(gl_world.intrinsics)
    x, up, z = np.eye(3)
    target, half_marker = gl_world.target_pose, gl_world.scenario.marker.size_m / 2
    faces = {
        gl_world.table_body: (np.array([0.42, TABLE_TOP_Y_M, 0.0]), up, (x, z), (0.28, 0.45)),
        gl_world.floor_body: (np.array([0.3, FLOOR_TOP_Y_M, 0.0]), up, (x, z), (1.5, 1.5)),
        gl_world.target_body: (
            target[:3, 3],
            target[:3, 2],
            (target[:3, 0], target[:3, 1]),
            (half_marker, half_marker),
        ),
    }
    for body, face in faces.items():
        rows, cols = np.nonzero(ids == body)
        expected, inside = ray_hits(gl_world.scenario, rows, cols, face)
        assert inside.sum() > 1000, body
        assert np.abs(depth[rows, cols][inside] - expected[inside]).max() < 1e-6, body


def test_gl_agrees_with_tinyrenderer_on_the_accuracy_postures(gl_world: World) -> None:
    """Vision's corners and depths from both renderers, on ``umay accuracy``'s postures with
    both markers wholly in view: within 0.05 px and 0.05 mm. Their id images agree on each
    marker's pixels."""
    scenario = gl_world.scenario
    tiny = World(load_scenario(None, parse_overrides(TINY)))
    compared = 0
    try:
        for q in sample_postures(scenario, 40, np.random.default_rng(0)):
            for w in (gl_world, tiny):
                w.reset(q)
                w.update_scene()
            seen = tiny.marker_visibility()
            if any(v.fraction < WHOLE or v.touched for v in seen.values()):
                continue
            images = [w.render_perfect(w.intrinsics) for w in (gl_world, tiny)]
            gl, ref = (measure_markers(rgb, d, w.intrinsics, scenario.vision) for rgb, d in images)
            for name in ("hand", "target"):
                assert gl[name].visible and ref[name].visible, name
                np.testing.assert_allclose(gl[name].corners_px, ref[name].corners_px, atol=0.05)
                np.testing.assert_allclose(gl[name].depth_m, ref[name].depth_m, atol=5e-5)
            ids_gl, ids_ref = (w.segmentation(w.intrinsics) for w in (gl_world, tiny))
            assert (ids_gl == ids_ref).mean() > 0.99  # limbs differ: Bullet's fat hull
            hand_id = gl_world.robot + ((gl_world.ee_link + 1) << 24)
            for marker in (gl_world.target_body, hand_id):
                a, b = ids_gl == marker, ids_ref == marker
                assert np.count_nonzero(a ^ b) <= 0.01 * np.count_nonzero(b), marker
            compared += 1
            if compared == 4:
                break
    finally:
        tiny.close()
    assert compared == 4


@pytest.mark.parametrize(
    "overrides",
    [
        [],
        [
            "marker.orientation_cue=true",
            "target.yaw=0.6",
            'events=[{at_s = 0.0, action = "occlude_hand", duration_s = 30.0}]',
        ],
    ],
)
def test_the_cached_scenery_gives_the_images_of_drawing_every_shape(overrides: list[str]) -> None:
    """OpenGL draws the torso, table and floor once into the background each frame starts from:
    bit for bit the images of drawing every shape every frame (the scenery last, as before
    the cache), colour and depth, on the accuracy postures, with an orientation cue and an
    occluding panel; and a scenery body moved after all is drawn where it is now, not where
    the cache saw it."""
    scenario = load_scenario(None, parse_overrides(overrides))
    cached, every = World(scenario), World(scenario, cache_scenery=False)
    try:
        if cached.renderer != "gl":
            pytest.fail(f"no OpenGL renderer on this machine: {cached.renderer_detail}")

        def same_images() -> None:
            (rgb_a, depth_a), (rgb_b, depth_b) = (
                w.render_perfect(w.intrinsics) for w in (cached, every)
            )
            assert np.array_equal(rgb_a, rgb_b)
            assert np.array_equal(depth_a.view(np.uint32), depth_b.view(np.uint32))

        for q in sample_postures(scenario, 12, np.random.default_rng(3)):
            for w in (cached, every):
                w.reset(q)
                w.update_scene()
            same_images()
        table_moved = np.array([0.45, TABLE_TOP_Y_M - 0.05, 0.02])
        for w in (cached, every):
            w.client.resetBasePositionAndOrientation(w.table_body, table_moved, (0, 0, 0, 1))
        same_images()
    finally:
        cached.close()
        every.close()


def test_no_opengl_falls_back_to_tinyrenderer_and_says_why(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    def refuse() -> None:
        raise GlUnavailable("no EGL OpenGL context (test: no driver)")

    monkeypatch.setattr(renderers, "GlRenderer", refuse)
    # An idle context left by an earlier test of this worker would be reused, not made.
    monkeypatch.setattr(renderers, "_idle_gl", [])
    with caplog.at_level(logging.WARNING):
        w = World(load_scenario(None, parse_overrides(SIZE)))
    try:
        assert w.renderer == "tiny" and "test: no driver" in w.renderer_detail
        assert sum("fell back" in r.getMessage() for r in caplog.records) == 1
        rgb, depth = w.render()
        assert rgb.shape == (240, 320, 3) and depth is not None and depth.max() > 0
    finally:
        w.close()


def test_a_second_occluding_panel_is_drawn_at_its_own_size() -> None:
    """Two overlapping hand occlusions: the second panel is made where the hand is then, its
    size from its distance to the camera. pybullet gives it the id the first one freed, and
    OpenGL still draws it from what the scene is now, not from the first panel's mesh."""
    events = (
        'events=[{at_s = 0.0, action = "occlude_hand", duration_s = 1.0}, '
        '{at_s = 0.5, action = "occlude_hand", duration_s = 1.0}]'
    )
    scenario = load_scenario(None, parse_overrides([*SIZE, events]))
    w = World(scenario)
    try:
        if w.renderer != "gl":
            pytest.fail(f"no OpenGL renderer on this machine: {w.renderer_detail}")
        w.update_scene()
        w.render_perfect(w.intrinsics)
        first = w.occluder_body
        w.reset(np.asarray(scenario.robot.q0) + np.array([0.3, 0.2, 0.0, 0.0, 0.0, 0.0]))
        w.sim_time_s = 0.5
        w.update_scene()
        assert w.occluder_body == first  # the freed id, reused
        w.render_perfect(w.intrinsics)
        drawn = [s.size_m for s in w._gl_shapes if s.body == w.occluder_body]
        assert drawn == [tuple(w.client.getVisualShapeData(w.occluder_body)[0][3])]
    finally:
        w.close()
