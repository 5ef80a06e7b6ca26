"""Which target corner each hand corner goes to: vision labels each square's corners on its own,
and a square turned by 90° looks the same, so the pairing is chosen (the least turn), with
hysteresis. Pure."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from common.kinematics import centroid
from common.marker import Marker

FloatArray = NDArray[np.float64]


def rolled(observation: Marker, shift: int) -> Marker:
    """The same marker with its corners relabelled: corner i becomes corner (i + shift) % 4."""
    if shift == 0:
        return observation
    return replace(
        observation,
        corners_px=cyclic(observation.corners_px, shift),
        depth_m=cyclic(observation.depth_m, shift),
        depth_sigma_m=cyclic(observation.depth_sigma_m, shift),
        points_m=cyclic(observation.points_m, shift),
    )


def cyclic(values: FloatArray, shift: int) -> FloatArray:
    """``np.roll(values, -shift, axis=0)``: entry i becomes entry (i + shift) % n (a copy),
    taken by index for a marker's four corners (np.roll's generic overhead, not its values)."""
    if len(values) != 4:
        return np.roll(values, -shift, axis=0)
    return values[_CYCLIC_PAIRINGS[shift % 4]]


# Another pairing of corners must cut the squared image error by this factor to replace the
# current one (hysteresis: near a 45° relative turn two pairings are almost as good).
CORNER_SWITCH_RATIO = 0.7


# Row k: the target corner each hand corner i goes to in pairing k, (i + k) % 4.
_CYCLIC_PAIRINGS = (np.arange(4)[None, :] + np.arange(4)[:, None]) % 4


def pairing_costs_px2(hand_px: FloatArray, target_px: FloatArray) -> FloatArray:
    """Squared shape mismatch (px²) for each of the 4 cyclic pairings of the hand's corners
    with the target's (entry k pairs hand corner i with target corner (i + k) % 4).

    The two squares look the same turned by 90°, so which target corner a hand corner must go
    to is a choice: vision labels each marker's corners on its own. The corners are compared
    about their centroids (the offset between the squares is the same for every pairing and
    would drown the difference), so the least cost is the pairing that needs the least turn
    about the optical axis; it is also the one with the least squared image error."""
    hand = hand_px - centroid(hand_px)
    target = target_px - centroid(target_px)
    return np.add.reduce((hand - target[_CYCLIC_PAIRINGS]) ** 2, axis=(1, 2))  # np.sum's


def choose_pairing(costs_px2: FloatArray, current: int | None) -> int:
    """The best pairing, unless the current one is nearly as good (hysteresis)."""
    best = int(np.argmin(costs_px2))
    if current is None or costs_px2[best] < CORNER_SWITCH_RATIO * costs_px2[current]:
        return best
    return current


def label_shift(previous_px: FloatArray, current_px: FloatArray) -> int:
    """The cyclic shift ``s`` of a marker's labels between two views of it close in time:
    its corner ``i`` now is its corner ``(i + s) % 4`` then (compared about the centroids, so
    the marker's move in between does not count; a turn past 45° in between would).

    Vision keeps a marker's labels from frame to frame, and labels its corners afresh when it
    has lost the marker or restarted; anything indexed by corner or by pairing must follow.
    The shift is the pairing of the view now with the view then that needs the least turn;
    0 at once for the same view to the bit (a still marker), whose pairing 0 costs 0."""
    previous_px, current_px = np.asarray(previous_px), np.asarray(current_px)
    if previous_px.shape == current_px.shape and previous_px.tobytes() == current_px.tobytes():
        return 0
    return int(pairing_costs_px2(current_px, previous_px).argmin())


def relabelled_pairing(pairing: int, hand_shift: int, target_shift: int) -> int:
    """The same physical pairing once the hand's labels shifted by ``hand_shift`` and the
    target's by ``target_shift`` (:func:`label_shift`)."""
    return (pairing + hand_shift - target_shift) % 4
