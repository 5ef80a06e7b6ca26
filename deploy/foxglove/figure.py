"""A picture of what the Foxglove view shows, drawn from an exported file (``umay export
--foxglove``): the colour image with the view's annotations (left) and the 3-D scene from the
view's transforms and scene entities (right), at one instant. Offline stand-in for a
screenshot of the Foxglove app, read back through the same schemas a client decodes.

    python -m deploy.foxglove.figure OUT.mcap docs/figures/foxglove_view.png [--time-s T]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from mcap.reader import make_reader

from common import kinematics as kin
from deploy.foxglove import topics, transforms
from deploy.foxglove.client import protobuf_class


def read_view(path: str | Path) -> dict[str, list[tuple[int, Any]]]:
    """Every message of an exported file, decoded with the schema it carries, by topic."""
    out: dict[str, list[tuple[int, Any]]] = {}
    classes: dict[int, Any] = {}
    with Path(path).open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            if channel.message_encoding == "json":
                value = json.loads(message.data)
            else:
                if schema.id not in classes:
                    classes[schema.id] = protobuf_class(schema.name, schema.data)
                value = classes[schema.id].FromString(message.data)
            out.setdefault(channel.topic, []).append((message.log_time, value))
    return out


def _at(messages: list[tuple[int, Any]], t_ns: int) -> Any:
    """The newest message at or before ``t_ns`` (the first one if none is)."""
    before = [m for t, m in messages if t <= t_ns]
    return before[-1] if before else messages[0][1]


def _rgba(col: Any) -> tuple[float, float, float, float]:
    return (col.r, col.g, col.b, col.a)


def draw_annotations(ax: Any, image: np.ndarray, ann: Any) -> None:
    ax.imshow(image)
    for p in ann.points:
        pts = np.array([[q.x, q.y] for q in p.points])
        if len(pts) == 0:
            continue
        colour = _rgba(p.outline_color)
        kind = p.type
        if kind == 1:  # POINTS
            ax.scatter(pts[:, 0], pts[:, 1], s=4, color=colour)
        elif kind == 4:  # LINE_LIST
            for a, b in pts.reshape(-1, 2, 2):
                ax.plot([a[0], b[0]], [a[1], b[1]], color=colour, lw=1)
        else:
            closed = np.vstack([pts, pts[:1]]) if kind == 2 else pts
            ax.plot(closed[:, 0], closed[:, 1], color=colour, lw=1.5)
    from matplotlib.patches import Circle

    for circ in ann.circles:
        ax.add_patch(
            Circle(
                (circ.position.x, circ.position.y), circ.diameter / 2, fill=False,
                color=_rgba(circ.outline_color), lw=1,
            )
        )  # fmt: skip
    for t in ann.texts:
        ax.text(t.position.x, t.position.y, t.text, color="white", fontsize=8,
                bbox={"facecolor": "black", "alpha": 0.5, "pad": 1, "lw": 0})  # fmt: skip
    ax.set_axis_off()


def _frames(tf: Any) -> dict[str, np.ndarray]:
    """Every frame's pose in ``world`` from one FrameTransforms message."""
    rel = {}
    for t in tf.transforms:
        r = transforms.rotation_from_quaternion(
            t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w
        )
        rel[t.child_frame_id] = (
            t.parent_frame_id,
            kin.homogeneous(r, np.array([t.translation.x, t.translation.y, t.translation.z])),
        )
    poses: dict[str, np.ndarray] = {topics.WORLD: np.eye(4)}

    def pose(frame: str) -> np.ndarray:
        if frame not in poses:
            parent, t = rel[frame]
            poses[frame] = pose(parent) @ t
        return poses[frame]

    for frame in rel:
        pose(frame)
    return poses


def draw_scene(ax: Any, view: dict[str, list[tuple[int, Any]]], t_ns: int) -> None:
    poses = _frames(_at(view[topics.TRANSFORMS], t_ns))
    chain = [topics.BASE, *topics.DH_FRAMES]
    arm = np.array([poses[f][:3, 3] for f in chain])
    ax.plot(arm[:, 0], arm[:, 1], arm[:, 2], "-o", color="0.45", lw=4, ms=3, label="arm (DH)")
    hand = poses[topics.HAND_MARKER]
    trail = np.array([_frames(tf)[topics.HAND_MARKER][:3, 3] for t, tf in view[topics.TRANSFORMS]
                      if t <= t_ns])  # fmt: skip
    ax.scatter(trail[:, 0], trail[:, 1], trail[:, 2], s=2, color="k", label="hand marker path")
    scene = [s for _t, upd in view[topics.SCENE] for s in upd.entities]
    by_id = {e.id: e for e in scene}  # the newest of each entity
    for entity_id, colour in (("target_marker", "red"), ("table", "tan"), ("torso", "slategrey")):
        e = by_id.get(entity_id)
        if e is None:
            continue
        cube = e.cubes[0]
        p, o, s = cube.pose.position, cube.pose.orientation, cube.size
        frame = poses[e.frame_id] @ kin.homogeneous(
            transforms.rotation_from_quaternion(o.x, o.y, o.z, o.w), np.array([p.x, p.y, p.z])
        )
        h = np.array([s.x, s.y, s.z]) / 2
        top = np.array([[-h[0], -h[1], h[2]], [h[0], -h[1], h[2]], [h[0], h[1], h[2]],
                        [-h[0], h[1], h[2]], [-h[0], -h[1], h[2]]])  # fmt: skip
        for face in (top, top * [1, 1, -1]):
            w = (frame @ np.c_[face, np.ones(5)].T).T
            ax.plot(w[:, 0], w[:, 1], w[:, 2], color=colour, lw=1.5)
    size_m = by_id["hand_marker"].cubes[0].size.x if "hand_marker" in by_id else 0.06
    marker = kin.marker_corners(hand, size_m)
    loop = np.vstack([marker, marker[:1]])
    ax.plot(loop[:, 0], loop[:, 1], loop[:, 2], color="green", lw=2, label="hand marker")
    for cam, colour in ((topics.CAMERA, "c"), (topics.CAMERA_TRUE, "m")):
        e = by_id.get(f"{cam}_frustum")
        if e is None:
            continue
        pts = np.array([[q.x, q.y, q.z, 1.0] for q in e.lines[0].points])
        w = (poses[cam] @ pts.T).T
        for a, b in w.reshape(-1, 2, 4):
            ax.plot([a[0], b[0]], [a[1], b[1]], [a[2], b[2]], color=colour, lw=0.6)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z up (m)")
    ax.set_box_aspect((1, 1, 1))
    centre = np.array([0.2, 0.05, -0.25])
    for setter, mid in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=True):
        setter(mid - 0.4, mid + 0.4)
    ax.view_init(elev=20, azim=-130)
    ax.legend(loc="upper left", fontsize=7)


def write_figure(view_path: str | Path, out: str | Path, time_s: float | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    view = read_view(view_path)
    last = view[topics.ANNOTATIONS][-1][0]
    t_ns = last if time_s is None else transforms.time_ns(time_s)
    jpeg = _at(view[topics.COLOUR_IMAGE], t_ns)
    image = cv2.cvtColor(cv2.imdecode(np.frombuffer(jpeg.data, np.uint8), 1), cv2.COLOR_BGR2RGB)
    fig = plt.figure(figsize=(13, 5.2))
    ax_img = fig.add_subplot(1, 2, 1)
    draw_annotations(ax_img, image, _at(view[topics.ANNOTATIONS], t_ns))
    ax_img.set_title(f"{topics.COLOUR_IMAGE} + {topics.ANNOTATIONS}", fontsize=9)
    ax3d = fig.add_subplot(1, 2, 2, projection="3d")
    draw_scene(ax3d, view, t_ns)
    ax3d.set_title(f"{topics.TRANSFORMS} + {topics.SCENE}", fontsize=9)
    fig.suptitle(f"umay view at t = {t_ns / 1e9:.2f} s (simulated)")
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m deploy.foxglove.figure", description=__doc__)
    p.add_argument("view", metavar="FOXGLOVE.mcap", help="written by umay export --foxglove")
    p.add_argument("out", metavar="OUT.png")
    p.add_argument("--time-s", type=float, default=None, help="simulated time (default: end)")
    args = p.parse_args(argv)
    print(write_figure(args.view, args.out, args.time_s))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
