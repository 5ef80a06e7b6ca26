"""The view's colours, shared by the image overlay and the 3-D scene."""

from __future__ import annotations

from foxglove.messages import Color

# Colours (r, g, b, a in 0..1).
WHITE = (1.0, 1.0, 1.0, 1.0)
GREEN = (0.1, 0.9, 0.2, 1.0)
RED = (1.0, 0.15, 0.15, 1.0)
ORANGE = (1.0, 0.6, 0.0, 1.0)
YELLOW = (1.0, 0.9, 0.1, 1.0)
CYAN = (0.1, 0.9, 1.0, 1.0)
MAGENTA = (1.0, 0.2, 1.0, 1.0)
GREY = (0.75, 0.75, 0.78, 1.0)
SKIN = (0.92, 0.90, 0.86, 1.0)
TORSO = (0.35, 0.37, 0.42, 1.0)
TABLE = (0.86, 0.84, 0.80, 1.0)
BLOCK = (0.45, 0.55, 0.70, 1.0)


def color(rgba: tuple[float, float, float, float]) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])
