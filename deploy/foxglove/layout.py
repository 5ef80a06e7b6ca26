"""The Foxglove layout of the view (``deploy/foxglove/layout.json``), built with the SDK's
layout types so that it names the view's topics from :mod:`deploy.foxglove.topics`.

The thesis's two views side by side (Fig. 5.18/5.19): what the Kinect sees with the markers,
the desired corners and the hand's trail (left), and the robot moving toward the object
(right); below them the plots (feature error, twist, joints, controller phase), the depth
image and the services' log. Regenerate the file with
``python -m deploy.foxglove.layout > deploy/foxglove/layout.json`` (a test checks it is up
to date). In Foxglove: Layouts → Import from file.
"""

from __future__ import annotations

import json

import foxglove.layouts as fl

from deploy.foxglove import topics


def _plot(title: str, series: list[tuple[str, str]]) -> fl.PlotPanel:
    return fl.PlotPanel(
        title=title,
        config=fl.PlotConfig(
            paths=[
                fl.PlotSeries(value=path, label=label, timestamp_method="receiveTime")
                for path, label in series
            ],
            show_legend=True,
            legend_display="floating",
            x_axis_val="timestamp",
        ),
    )


def _joints(topic: str, field: str) -> list[tuple[str, str]]:
    return [
        (f'{topic}.joints[:]{{name=="{n}"}}.{field}', f"{n} {field}") for n in topics.JOINT_NAMES
    ]


def build_layout() -> fl.Layout:
    camera_view = fl.ImagePanel(
        title="Kinect colour: markers, s*, trail (Fig. 5.10-5.16)",
        config=fl.ImageConfig(
            image_mode=fl.ImageModeConfig(
                image_topic=topics.COLOUR_IMAGE,
                calibration_topic=topics.CALIBRATION,
                annotations={topics.ANNOTATIONS: fl.ImageAnnotationSettings(visible=True)},
            ),
        ),
    )
    robot_view = fl.ThreeDeePanel(
        title="UMay arm, table, markers, camera (Fig. 5.18/5.19)",
        config=fl.ThreeDeeConfig(
            follow_tf=topics.WORLD,
            follow_mode="follow-pose",
            camera_state=fl.ThreeDeeCameraState(
                distance=1.6,
                perspective=True,
                phi=60.0,
                theta_offset=200.0,
                target=(0.2, -0.2, 0.0),
            ),
            topics={
                topics.SCENE: fl.BaseRendererSceneUpdateTopicSettings(visible=True),
                topics.TRUTH_SCENE: fl.BaseRendererSceneUpdateTopicSettings(visible=True),
            },
        ),
    )
    depth_view = fl.ImagePanel(
        title="Kinect depth (m)",
        config=fl.ImageConfig(
            image_mode=fl.ImageModeConfig(
                image_topic=topics.DEPTH_IMAGE,
                color_mode="colormap",
                color_map="turbo",
                min_value=0.3,
                max_value=1.2,
            ),
        ),
    )
    error = _plot(
        "feature error (px)",
        [(f"{topics.FEATURE_ERROR}.error_px_rms", "e rms (px)")]
        + [(f"{topics.FEATURE_ERROR}.error_px[{i}]", f"e[{i}]") for i in range(8)],
    )
    twist = _plot(
        "commanded twist (base frame)",
        [(f"{topics.TWIST}.linear_m_s[{i}]", f"v{a} (m/s)") for i, a in enumerate("xyz")]
        + [(f"{topics.TWIST}.angular_rad_s[{i}]", f"w{a} (rad/s)") for i, a in enumerate("xyz")]
        + [(f"{topics.TWIST}.speed_m_s", "|v| (m/s)")],
    )
    positions = _plot("joint positions (rad)", _joints(topics.JOINT_STATES, "position"))
    velocities = _plot("joint velocities (rad/s)", _joints(topics.JOINT_STATES, "velocity"))
    phase = _plot(
        "controller phase (0 servoing, 1 holding, 2 converged)",
        [(f"{topics.PHASE}.phase_code", "phase")],
    )
    logs = fl.LogPanel(
        title="services and controller", config=fl.LogConfig(topic_to_render=topics.LOG)
    )

    def split(direction: str, *items: tuple[float, object]) -> fl.SplitContainer:
        return fl.SplitContainer(
            direction=direction,  # type: ignore[arg-type]
            items=[fl.SplitItem(proportion=p, content=content) for p, content in items],
        )

    return fl.Layout(
        content=split(
            "column",
            (3.0, split("row", (1.0, camera_view), (1.0, robot_view))),
            (
                2.0,
                split(
                    "row",
                    (1.0, split("column", (1.0, error), (1.0, twist))),
                    (1.0, split("column", (1.0, positions), (1.0, velocities))),
                    (1.0, split("column", (1.0, phase), (1.0, depth_view), (1.0, logs))),
                ),
            ),
        )
    )


def layout_json() -> str:
    """The layout as the checked-in file holds it (indented, one trailing newline)."""
    return json.dumps(json.loads(build_layout().to_json()), indent=2) + "\n"


if __name__ == "__main__":
    print(layout_json(), end="")
