"""The scenario's ``[sim]`` table: physics rate, renderer, and the sim's own stops."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from common.config.base import Strict


class SimConfig(Strict):
    physics_hz: float = Field(
        240.0, ge=30.0, le=2000.0, description="physics steps per simulated second"
    )
    renderer: Literal["gl", "tiny"] = Field(
        "gl",
        description="gl: OpenGL through a headless EGL context (a GPU's driver, else Mesa's "
        "llvmpipe on the CPU), exact float32 depth; falls back to tiny, saying why, where no "
        "EGL context can be made. tiny: pybullet's TinyRenderer, the reference it is tested "
        "against",
    )
    command_watchdog_s: float = Field(
        0.3, gt=0.0, le=5.0, description="realtime: motors stop when commands stop this long"
    )
    lockstep_resend_s: float = Field(
        1.0, gt=0.0, description="re-publish a frame whose command has not come back (wall s)"
    )
    realtime_command_wait_s: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="realtime: after a frame, physics runs on but the next render waits this "
        "long at most (wall s) for that frame's joint command; a render holds the interpreter, "
        "so a command arriving during one would be applied only after it (0: render back to "
        "back)",
    )
