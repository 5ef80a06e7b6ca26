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
"""

from __future__ import annotations

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
in vec3 in_position;
in vec3 in_normal;
out float z_m;
out vec3 normal_cam;
void main() {
    vec4 p = cam_from_shape * vec4(in_position, 1.0);
    z_m = p.z;
    normal_cam = mat3(cam_from_shape) * in_normal;
    gl_Position = vec4(pinhole.x * p.x + pinhole.y * p.z, pinhole.z * p.y + pinhole.w * p.z,
                       depth_ab.x * p.z + depth_ab.y, p.z);
}
"""

FRAGMENT_SHADER = """
#version 330
uniform vec3 light_cam;  // towards the light, unit
uniform vec4 colour;
uniform int segment_id;
uniform vec2 shading;  // ambient, diffuse
in float z_m;
in vec3 normal_cam;
layout(location = 0) out vec4 out_colour;
layout(location = 1) out float out_depth;
layout(location = 2) out int out_id;
void main() {
    float lambert = max(dot(normalize(normal_cam), light_cam), 0.0);
    out_colour = vec4(colour.rgb * (shading.x + shading.y * lambert), 1.0);
    out_depth = z_m;
    out_id = segment_id;
}
"""


# The background: drawn first over the whole image, without depth test or depth writes.
BACKGROUND_VERTEX_SHADER = """
#version 330
in vec2 in_corner;
void main() { gl_Position = vec4(in_corner, 1.0, 1.0); }
"""

BACKGROUND_FRAGMENT_SHADER = """
#version 330
uniform vec3 colour;
layout(location = 0) out vec4 out_colour;
layout(location = 1) out float out_depth;
layout(location = 2) out int out_id;
void main() {
    out_colour = vec4(colour, 1.0);
    out_depth = 0.0;  // nothing: a Kinect's invalid depth
    out_id = -1;
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
class _Target:
    """A framebuffer of one size with its three attachments and read-back arrays."""

    fbo: object
    shape: tuple[int, int]  # rows, columns


class GlRenderer:
    """Draws :class:`~services.sim.shapes.VisualShape` lists from a camera pose.

    Meshes are uploaded once per shape list (:meth:`set_shapes` when bodies are made or
    removed); each frame only the shapes' poses change."""

    def __init__(self) -> None:
        import moderngl

        self._moderngl = moderngl
        self.ctx = open_context()
        ctx = self.ctx
        self.description = f"{ctx.info['GL_RENDERER']} (OpenGL {ctx.info['GL_VERSION']})"
        self.program = ctx.program(vertex_shader=VERTEX_SHADER, fragment_shader=FRAGMENT_SHADER)
        self.program["shading"].value = (AMBIENT, DIFFUSE)
        background = ctx.program(
            vertex_shader=BACKGROUND_VERTEX_SHADER, fragment_shader=BACKGROUND_FRAGMENT_SHADER
        )
        background["colour"].value = BACKGROUND_RGB
        corners = np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32)
        self._background = ctx.vertex_array(
            background, [(ctx.buffer(corners.tobytes()), "2f", "in_corner")]
        )
        self._meshes: list[tuple[VisualShape, object]] = []
        self._buffers: list[object] = []
        self._targets: dict[tuple[int, int], _Target] = {}

    @property
    def is_software(self) -> bool:
        """True on Mesa's CPU rasterisers (llvmpipe, softpipe), False on a GPU driver."""
        renderer = self.ctx.info["GL_RENDERER"].lower()
        return any(name in renderer for name in ("llvmpipe", "softpipe", "swrast"))

    def set_shapes(self, shapes: list[VisualShape]) -> None:
        """Upload the meshes of ``shapes`` (replacing the previous ones)."""
        for buffer in self._buffers:
            buffer.release()
        self._meshes, self._buffers = [], []
        for shape in shapes:
            vertices, normals = shape_mesh(shape)
            data = np.hstack([vertices, normals]).astype(np.float32)
            buffer = self.ctx.buffer(data.tobytes())
            vao = self.ctx.vertex_array(
                self.program, [(buffer, "3f 3f", "in_position", "in_normal")]
            )
            self._buffers.append(buffer)
            self._meshes.append((shape, vao))

    def _target(self, k: CameraIntrinsics) -> _Target:
        size = (k.width_px, k.height_px)
        if size not in self._targets:
            ctx = self.ctx
            colour = ctx.renderbuffer(size, components=4, dtype="f1")
            depth = ctx.renderbuffer(size, components=1, dtype="f4")
            ids = ctx.renderbuffer(size, components=1, dtype="i4")
            z_buffer = ctx.depth_renderbuffer(size)
            fbo = ctx.framebuffer(color_attachments=[colour, depth, ids], depth_attachment=z_buffer)
            self._targets[size] = _Target(fbo, (k.height_px, k.width_px))
        return self._targets[size]

    def draw(
        self,
        poses: list[FloatArray],
        cam_from_world: FloatArray,
        k: CameraIntrinsics,
        near_m: float,
        far_m: float,
        light_direction_world: FloatArray,
    ) -> _Target:
        """Draw every shape at its world pose (same order as :meth:`set_shapes`) into the
        framebuffer of ``k``'s size; read nothing back yet."""
        target = self._target(k)
        ctx, program = self.ctx, self.program
        target.fbo.use()
        # clear() would set all three attachments to one value; depth must read 0, ids -1.
        target.fbo.clear(depth=1.0)
        ctx.enable_only(self._moderngl.NOTHING)
        self._background.render(self._moderngl.TRIANGLE_STRIP)
        ctx.enable_only(self._moderngl.DEPTH_TEST)
        program["pinhole"].value = pinhole_uniforms(k)
        program["depth_ab"].value = depth_uniforms(near_m, far_m)
        light = cam_from_world[:3, :3] @ np.asarray(light_direction_world, float)
        program["light_cam"].value = tuple(light / np.linalg.norm(light))
        for (shape, vao), pose in zip(self._meshes, poses, strict=True):
            cam_from_shape = cam_from_world @ pose
            program["cam_from_shape"].write(cam_from_shape.astype(np.float32).tobytes("F"))
            program["colour"].value = shape.rgba
            program["segment_id"].value = shape.segment_id
            vao.render()
        return target

    def read_colour_depth(self, target: _Target) -> tuple[np.ndarray, np.ndarray]:
        """RGB uint8 (H, W, 3) and depth float32 metres (H, W; 0 where nothing is drawn), as
        fresh arrays (the caller may keep them)."""
        rgb = np.empty((*target.shape, 3), np.uint8)
        depth_m = np.empty(target.shape, np.float32)
        target.fbo.read_into(rgb, components=3, attachment=0)
        target.fbo.read_into(depth_m, components=1, attachment=1, dtype="f4")
        return rgb, depth_m

    def read_ids(self, target: _Target) -> np.ndarray:
        """The id image (int32, -1 where nothing is drawn) of the last draw into ``target``."""
        ids = np.empty(target.shape, np.int32)
        target.fbo.read_into(ids, components=1, attachment=2, dtype="i4")
        return ids

    def release(self) -> None:
        self.ctx.release()
