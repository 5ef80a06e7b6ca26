"""One square marker as vision produces it and the controller consumes it, and its wire form.

Vision measures markers, the wire format carries them (:class:`common.messages.MarkerFeatures`)
and the controller acts on them: one type, :class:`Marker`, with the wire's field names, so
the three cannot drift apart. It holds numpy arrays (what both services compute with); the
wire model holds lists (what pydantic validates and the recordings store), and
:meth:`Marker.to_wire` / :meth:`Marker.from_wire` convert between the two without touching a
value. Whether a marker is visible or usable is decided here, by the rule the wire format
defines (:func:`common.messages.is_usable`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from common.camera import CameraIntrinsics, project
from common.messages import MarkerFeatures, MarkerState, is_usable

FloatArray = NDArray[np.float64]


# eq=False: the fields are arrays, whose ``==`` is elementwise; two markers are compared by
# their fields where a test needs it. kw_only: the four arrays have similar shapes, so a
# positional call could swap two of them silently.
@dataclass(frozen=True, eq=False, kw_only=True)
class Marker:
    """One marker in one camera frame (the meaning of each field is
    :class:`~common.messages.MarkerFeatures`'s).

    ``corners_px`` (4, 2) sub-pixel (u, v); ``depth_m`` (4,) Z of each corner and
    ``depth_sigma_m`` (4,) its 1-σ uncertainty; ``points_m`` (4, 3) the corners in the camera
    optical frame. ``state``: ``visible``, ``partial``, ``lost`` or ``no_depth``; the arrays
    are zeros unless it is ``visible`` or ``fitted`` (a partly hidden marker whose corners were
    fitted from its visible edges). ``occluded``: something is seen in front of it (hidden,
    not gone; None: vision cannot tell). ``reason``: why it is not visible.
    """

    state: MarkerState
    corners_px: FloatArray
    depth_m: FloatArray
    depth_sigma_m: FloatArray
    points_m: FloatArray
    occluded: bool | None = False
    fitted: bool = False
    reason: str = ""

    @property
    def visible(self) -> bool:
        """Seen whole, with depth."""
        return self.state == "visible"

    @property
    def usable(self) -> bool:
        """Corners and depths can be acted on: seen whole, or fitted from what is seen."""
        return is_usable(self.state, self.fitted)

    @classmethod
    def unseen(cls, state: MarkerState, reason: str = "", occluded: bool | None = False) -> Marker:
        """A marker that cannot be used (``state`` not ``visible``): zero arrays."""
        return cls(
            state=state,
            corners_px=np.zeros((4, 2)),
            depth_m=np.zeros(4),
            depth_sigma_m=np.zeros(4),
            points_m=np.zeros((4, 3)),
            occluded=occluded,
            reason=reason,
        )

    @classmethod
    def seen_at(
        cls, points_m: FloatArray, k: CameraIntrinsics, depth_sigma_m: FloatArray | None = None
    ) -> Marker:
        """A whole marker whose corners are ``points_m`` (4, 3, camera optical frame), as the
        camera ``k`` sees them; ``depth_sigma_m`` (4,) their uncertainty (None: zeros)."""
        return cls(
            state="visible",
            corners_px=project(points_m, k),
            depth_m=points_m[:, 2].copy(),
            depth_sigma_m=np.zeros(4) if depth_sigma_m is None else depth_sigma_m,
            points_m=points_m,
        )

    def to_wire(self) -> MarkerFeatures:
        """The wire form (validated: a marker out of range raises ``ValidationError``)."""
        return MarkerFeatures(
            state=self.state,
            corners_px=self.corners_px.tolist(),
            depth_m=self.depth_m.tolist(),
            depth_sigma_m=self.depth_sigma_m.tolist(),
            points_m=self.points_m.tolist(),
            occluded=self.occluded,
            fitted=self.fitted,
            reason=self.reason,
        )

    @classmethod
    def from_wire(cls, m: MarkerFeatures) -> Marker:
        """A marker received on the wire, as arrays (float64, the values unchanged)."""
        return cls(
            state=m.state,
            corners_px=np.array(m.corners_px, dtype=float),
            depth_m=np.array(m.depth_m, dtype=float),
            depth_sigma_m=np.array(m.depth_sigma_m, dtype=float),
            points_m=np.array(m.points_m, dtype=float),
            occluded=m.occluded,
            fitted=m.fitted,
            reason=m.reason,
        )
