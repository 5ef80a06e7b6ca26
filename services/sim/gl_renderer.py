"""OpenGL renderer of the simulated camera: colour, exact metric depth and an id image in one pass.

Drawn through ``moderngl`` on a headless EGL context: a GPU's driver where the host has one,
Mesa's llvmpipe on the CPU otherwise (``GL_RENDERER`` says which; ``umay status`` shows it).

The vertex shader projects points given in the camera's *optical* frame (x right, y down, z
forward) straight with the pinhole model of :mod:`common.camera`: pixel (row i, column j) is
sampled at ``u = j, v = i``, the same rays TinyRenderer samples once its half-pixel shift is
applied. Image row 0 lands in the framebuffer's first row, so no flip is needed on read-back.
Each fragment writes

- colour: the shape's colour, Lambert-shaded with pybullet's TinyRenderer coefficients;
- depth: Z along the optical axis in float32 metres, interpolated (perspective-correct, so
  exact for planar faces) rather than recovered from a non-linear 24-bit depth buffer;
- id: pybullet's segmentation value (body + ((link + 1) << 24)), -1 where nothing is drawn.

Scenery that never moves (the world names it: torso, table, floor) is drawn once into a
background framebuffer, which each frame is copied from before the rest is drawn over it: on a
CPU rasteriser the large boxes cost most of a frame. The background is drawn again whenever
anything it depends on changes (camera, intrinsics, light, meshes, the scenery's own poses), so
it is only ever an optimisation: the images are those of drawing the scenery first every frame.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from common.camera import CameraIntrinsics
from services.sim.shapes import VisualShape, shape_mesh

FloatArray = np.ndarray

# TinyRenderer's shading (pybullet's TinyRendererVisualShapeConverter defaults).
AMBIENT = 0.6
DIFFUSE = 0.35
BACKGROUND_RGB = (1.0, 1.0, 1.0)

VERTEX_SHADER = """
#version 330
uniform mat4 cam_from_shape;
uniform vec4 pinhole;  // x_ndc = a·X/Z + b, y_ndc = c·Y/Z + d
uniform vec2 depth_ab;  // z_ndc = A + B/Z: near → -1, far → +1
uniform vec3 light_cam;  // towards the light, unit
uniform vec4 colour;
uniform vec2 shading;  // ambient, diffuse
in vec3 in_position;
in vec3 in_normal;
out float z_m;
out vec3 shaded;
void main() {
    vec4 p = cam_from_shape * vec4(in_position, 1.0);
    z_m = p.z;
    // Lambert per vertex: exact on flat faces (every box), Gouraud on a cylinder's sides. Per
    // fragment it doubles llvmpipe's rasterisation time for no visible difference.
    float lambert = max(dot(normalize(mat3(cam_from_shape) * in_normal), light_cam), 0.0);
    shaded = colour.rgb * (shading.x + shading.y * lambert);
    gl_Position = vec4(pinhole.x * p.x + pinhole.y * p.z, pinhole.z * p.y + pinhole.w * p.z,
                       depth_ab.x * p.z + depth_ab.y, p.z);
}
"""

FRAGMENT_SHADER = """
#version 330
in float z_m;
in vec3 shaded;
layout(location = 0) out vec4 out_colour;
layout(location = 1) out float out_depth;
void main() {
    out_colour = vec4(shaded, 1.0);
    out_depth = z_m;
}
"""

# The id image has a pass of its own: frames, drawn every camera period, never need it.
ID_VERTEX_SHADER = """
#version 330
uniform mat4 cam_from_shape;
uniform vec4 pinhole;
uniform vec2 depth_ab;
in vec3 in_position;
void main() {
    vec4 p = cam_from_shape * vec4(in_position, 1.0);
    gl_Position = vec4(pinhole.x * p.x + pinhole.y * p.z, pinhole.z * p.y + pinhole.w * p.z,
                       depth_ab.x * p.z + depth_ab.y, p.z);
}
"""

ID_FRAGMENT_SHADER = """
#version 330
uniform int segment_id;
layout(location = 0) out int out_id;
void main() {
    out_id = segment_id + 1;  // 0 is the cleared background: read back as -1
}
"""


class GlUnavailable(RuntimeError):
    """No OpenGL context could be made (no libEGL, no driver, no moderngl)."""


def pinhole_uniforms(k: CameraIntrinsics) -> tuple[float, float, float, float]:
    """(a, b, c, d) with ``x_ndc = a·x + b``, ``y_ndc = c·y + d`` for normalised ``x, y``.

    OpenGL samples window pixel j at ``x_w = j + 0.5``, ``x_ndc = 2·x_w/W − 1``; asking
    ``u = fx·x + cx`` to land on ``j`` gives the terms below (rows likewise, with row 0 at the
    framebuffer's first row)."""
    w, h = k.width_px, k.height_px
    return (
        2.0 * k.fx_px / w,
        2.0 * (k.cx_px + 0.5) / w - 1.0,
        2.0 * k.fy_px / h,
        2.0 * (k.cy_px + 0.5) / h - 1.0,
    )


def depth_uniforms(near_m: float, far_m: float) -> tuple[float, float]:
    """(A, B) with ``z_ndc = A + B/Z``: −1 at ``near_m``, +1 at ``far_m``."""
    return (far_m + near_m) / (far_m - near_m), -2.0 * far_m * near_m / (far_m - near_m)


def open_context() -> object:
    """A headless EGL OpenGL 3.3+ context, or :class:`GlUnavailable` saying why not."""
    try:
        import moderngl
    except ImportError as exc:
        raise GlUnavailable(f"moderngl is not installed ({exc})") from exc
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as exc:  # glcontext raises plain Exceptions for every EGL failure
        raise GlUnavailable(f"no EGL OpenGL context ({exc})") from exc
    return ctx


@dataclass
class _Layers:
    """A colour and metric-depth framebuffer with its z-buffer, and a framebuffer of its colour
    attachment alone, to clear that to the background colour."""

    frame: object
    clear_colour: object


@dataclass
class _Target:
    """Framebuffers of one size: the frame's, the scenery drawn alone (copied into the frame
    before the moving shapes are drawn), and the id image's."""

    frame: _Layers
    background: _Layers
    ids: object
    shape: tuple[int, int]  # rows, columns
    background_key: tuple = ()  # what the background was drawn for (empty: not yet)


def _or_empty(array: np.ndarray | None, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """``array`` to read pixels into, or a fresh one; ValueError when it does not fit them
    (``read_into`` would write past it)."""
    if array is None:
        return np.empty(shape, dtype)
    if array.shape != shape or array.dtype != dtype or not array.flags.c_contiguous:
        raise ValueError(f"cannot read a {np.dtype(dtype)} {shape} image into {array.shape}")
    return array


class GlRenderer:
    """Draws :class:`~services.sim.shapes.VisualShape` lists from a camera pose.

    Meshes are uploaded once per shape list (:meth:`set_shapes` when bodies are made or
    removed); each frame only the shapes' poses change."""

    def __init__(self) -> None:
        self.ctx = open_context()
        ctx = self.ctx
        self.description = f"{ctx.info['GL_RENDERER']} (OpenGL {ctx.info['GL_VERSION']})"
        self.program = ctx.program(vertex_shader=VERTEX_SHADER, fragment_shader=FRAGMENT_SHADER)
        self.program["shading"].value = (AMBIENT, DIFFUSE)
        self.id_program = ctx.program(
            vertex_shader=ID_VERTEX_SHADER, fragment_shader=ID_FRAGMENT_SHADER
        )
        self._meshes: list[tuple[VisualShape, object, object]] = []
        self._buffers: list[object] = []
        self._targets: dict[tuple[int, int], _Target] = {}
        self._scenery: list[int] = []  # indices of the meshes drawn into the background
        self._moving: list[int] = []  # ... and of those drawn every frame
        self._meshes_version = 0  # a background of older meshes is drawn again

    def _make_current(self) -> None:
        # GL calls go to the thread's current context, the last one made or entered: with
        # several renderers in a process (worlds open at once, a context kept for the next
        # world) this one must be made current first. Entered, never exited: exiting would
        # make current again a context that may since have been released.
        self.ctx.__enter__()

    @property
    def is_software(self) -> bool:
        """True on Mesa's CPU rasterisers (llvmpipe, softpipe), False on a GPU driver."""
        renderer = self.ctx.info["GL_RENDERER"].lower()
        return any(name in renderer for name in ("llvmpipe", "softpipe", "swrast"))

    def set_shapes(
        self, shapes: list[VisualShape], scenery_bodies: frozenset[int] = frozenset()
    ) -> None:
        """Upload the meshes of ``shapes`` (replacing the previous ones). The shapes of
        ``scenery_bodies``, bodies that do not move, are drawn into the cached background."""
        self.release_meshes()
        self._meshes_version += 1
        self._scenery = [i for i, shape in enumerate(shapes) if shape.body in scenery_bodies]
        self._moving = [i for i, shape in enumerate(shapes) if shape.body not in scenery_bodies]
        self._make_current()
        for shape in shapes:
            vertices, normals = shape_mesh(shape)
            data = np.hstack([vertices, normals]).astype(np.float32)
            buffer = self.ctx.buffer(data.tobytes())
            vao = self.ctx.vertex_array(
                self.program, [(buffer, "3f 3f", "in_position", "in_normal")]
            )
            id_vao = self.ctx.vertex_array(self.id_program, [(buffer, "3f 12x", "in_position")])
            self._buffers.append(buffer)
            self._meshes.append((shape, vao, id_vao))

    def release_meshes(self) -> None:
        """Free the meshes (vertex arrays and buffers): moderngl frees nothing on garbage
        collection, so a context drawing world after world must release them itself."""
        self._make_current()
        for _shape, vao, id_vao in self._meshes:
            vao.release()
            id_vao.release()
        for buffer in self._buffers:
            buffer.release()
        self._meshes, self._buffers = [], []

    def _layers(self, size: tuple[int, int]) -> _Layers:
        ctx = self.ctx
        colour = ctx.renderbuffer(size, components=4, dtype="f1")
        depth = ctx.renderbuffer(size, components=1, dtype="f4")
        return _Layers(
            frame=ctx.framebuffer(
                color_attachments=[colour, depth], depth_attachment=ctx.depth_renderbuffer(size)
            ),
            clear_colour=ctx.framebuffer(color_attachments=[colour]),
        )

    def _target(self, k: CameraIntrinsics) -> _Target:
        size = (k.width_px, k.height_px)
        if size not in self._targets:
            ctx = self.ctx
            ids = ctx.renderbuffer(size, components=1, dtype="i4")
            self._targets[size] = _Target(
                frame=self._layers(size),
                background=self._layers(size),
                ids=ctx.framebuffer(
                    color_attachments=[ids], depth_attachment=ctx.depth_renderbuffer(size)
                ),
                shape=(k.height_px, k.width_px),
            )
        return self._targets[size]

    def draw(
        self,
        poses: list[FloatArray],
        cam_from_world: FloatArray,
        k: CameraIntrinsics,
        near_m: float,
        far_m: float,
        light_direction_world: FloatArray,
        ids: bool = False,
    ) -> _Target:
        """Draw every shape at its world pose (same order as :meth:`set_shapes`) into the
        colour and depth framebuffer of ``k``'s size, or with ``ids`` into the id image's;
        read nothing back yet. Colour and depth start from the cached background (the
        scenery), drawn again first if what it shows has changed."""
        if len(poses) != len(self._meshes):
            raise ValueError(f"{len(poses)} poses for {len(self._meshes)} shapes")
        self._make_current()
        target = self._target(k)
        program = self.id_program if ids else self.program
        program["pinhole"].value = pinhole_uniforms(k)
        program["depth_ab"].value = depth_uniforms(near_m, far_m)
        if ids:
            self._clear(target.ids, None)
            self._draw_meshes(target.ids, range(len(self._meshes)), poses, cam_from_world, ids)
            return target
        light = cam_from_world[:3, :3] @ np.asarray(light_direction_world, float)
        program["light_cam"].value = tuple(light / np.linalg.norm(light))
        frame, background = target.frame, target.background
        if not self._scenery:
            self._clear(frame.frame, frame.clear_colour)
        else:
            key = (
                self._meshes_version, k, cam_from_world.tobytes(), near_m, far_m, light.tobytes(),
                *(poses[i].tobytes() for i in self._scenery),
            )  # fmt: skip
            if target.background_key != key:
                self._clear(background.frame, background.clear_colour)
                self._draw_meshes(background.frame, self._scenery, poses, cam_from_world)
                target.background_key = key
            # Every attachment and the z-buffer: the moving shapes are depth-tested against it.
            self.ctx.copy_framebuffer(frame.frame, background.frame)
        self._draw_meshes(frame.frame, self._moving, poses, cam_from_world)
        return target

    @staticmethod
    def _clear(fbo: object, clear_colour: object | None) -> None:
        # Clears, not a full-screen background quad (on a CPU rasteriser a clear costs a
        # fraction of a quad's fragments): everything to 0 (depth 0 is a Kinect's invalid, id 0
        # reads back as -1), then the colour attachment alone to the background's white.
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        if clear_colour is not None:
            clear_colour.clear(*BACKGROUND_RGB, 1.0)

    def _draw_meshes(
        self,
        fbo: object,
        indices: Iterable[int],
        poses: list[FloatArray],
        cam_from_world: FloatArray,
        ids: bool = False,
    ) -> None:
        """Draw the meshes ``indices`` at their ``poses`` into ``fbo``, depth-tested, with the
        program's view uniforms as :meth:`draw` set them."""
        import moderngl

        program = self.id_program if ids else self.program
        fbo.use()
        self.ctx.enable_only(moderngl.DEPTH_TEST)
        for i in indices:
            shape, vao, id_vao = self._meshes[i]
            cam_from_shape = cam_from_world @ poses[i]
            program["cam_from_shape"].write(cam_from_shape.astype(np.float32).tobytes("F"))
            if ids:
                program["segment_id"].value = shape.segment_id
                id_vao.render()
            else:
                program["colour"].value = shape.rgba
                vao.render()

    def read_colour_depth(
        self,
        target: _Target,
        out: tuple[np.ndarray | None, np.ndarray | None] = (None, None),
    ) -> tuple[np.ndarray, np.ndarray]:
        """RGB uint8 (H, W, 3) and depth float32 metres (H, W; 0 where nothing is drawn), read
        into ``out``'s arrays where given (C-contiguous, of that shape and dtype: a camera
        frame's ring slot, say, so that the pixels are never copied again), else into fresh
        arrays (the caller may keep them)."""
        rgb = _or_empty(out[0], (*target.shape, 3), np.uint8)
        depth_m = _or_empty(out[1], target.shape, np.float32)
        target.frame.frame.read_into(rgb, components=3, attachment=0)
        target.frame.frame.read_into(depth_m, components=1, attachment=1, dtype="f4")
        return rgb, depth_m

    def read_ids(self, target: _Target) -> np.ndarray:
        """The id image (int32, -1 where nothing is drawn) of the last id draw into ``target``."""
        ids = np.empty(target.shape, np.int32)
        target.ids.read_into(ids, components=1, attachment=0, dtype="i4")
        ids -= 1
        return ids

    def release(self) -> None:
        self.ctx.release()
