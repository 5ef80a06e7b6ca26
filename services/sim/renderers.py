"""Which renderer draws a world: OpenGL where an EGL context can be made, TinyRenderer where it
cannot (said once, loudly) or where the scenario asks for it; and the OpenGL contexts of closed
worlds kept for the next world of the process."""

from __future__ import annotations

import logging
import os

from services.sim.gl_renderer import GlRenderer, GlUnavailable

log = logging.getLogger(__name__)

# OpenGL renderers of closed worlds, kept for the next world of this process: making and
# destroying an EGL context per world leaks native memory, and a domain study opens thousands.
_idle_gl: list[GlRenderer] = []
_inherited_gl: list[GlRenderer] = []  # a fork's parent's: never used, never released here


def _forget_idle_gl() -> None:  # a forked child must not draw through its parent's contexts
    _inherited_gl.extend(_idle_gl)
    _idle_gl.clear()


os.register_at_fork(after_in_child=_forget_idle_gl)


def open_renderer(requested: str) -> tuple[str, str, GlRenderer | None]:
    """The renderer to use for ``sim.renderer = requested``: (name, detail, OpenGL renderer or
    None). "gl" falls back to "tiny", once and loudly, where no EGL context can be made. An
    idle OpenGL renderer of this process is reused (:func:`close_renderer`)."""
    if requested == "tiny":
        return "tiny", "TinyRenderer (pybullet, CPU), as configured", None
    try:
        gl = _idle_gl.pop() if _idle_gl else GlRenderer()
    except GlUnavailable as exc:
        detail = f"TinyRenderer: OpenGL unavailable: {exc}"
        log.warning("sim.renderer = 'gl' fell back to %s", detail)
        return "tiny", detail, None
    kind = "software, CPU" if gl.is_software else "GPU"
    return "gl", f"OpenGL through EGL: {gl.description} ({kind})", gl


def close_renderer(gl: GlRenderer) -> None:
    """Free a closed world's meshes and keep its context for the next world; a second idle
    one (two worlds were open at once) is released."""
    gl.release_meshes()
    if _idle_gl:
        gl.release()
    else:
        _idle_gl.append(gl)
