"""Write the Foxglove layout for one robot (``configs/foxglove_layout.json`` for ``panda``, sim.yaml's name).

Built with foxglove-sdk's typed layout model (``foxglove.layouts``) rather than hand-written JSON, so a
panel or field name the app does not know fails here. Topic names carry the robot's name
(``adaptiveh/<name>/...``), hence one file per name: ``python scripts/foxglove_layout.py --name NAME``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import foxglove.layouts as fl


def layout(name: str) -> fl.Layout:
    """3D scene | camera; plots of distance and return, retreat statistic vs threshold; safety log."""

    def topic(suffix: str) -> str:
        return f"adaptiveh/{name}/{suffix}"

    def path(suffix: str, field: str) -> str:
        return f'"{topic(suffix)}".{field}'  # quoted: our topic names have no leading slash

    scene = fl.ThreeDeePanel(
        title="scene: arm, target, executed path (blue), plan (green), cut plan (red)",
        config=fl.ThreeDeeConfig(
            follow_tf="base",
            fixed_frame="base",
            follow_mode="follow-none",
            camera_state=fl.ThreeDeeCameraState(
                distance=2.2, phi=55.0, theta_offset=135.0, target_offset=(0.4, 0.0, 0.2)
            ),
            topics={
                topic("foxglove/scene"): fl.BaseRendererSceneUpdateTopicSettings(visible=True),
                topic("foxglove/robot"): fl.BaseRendererSceneUpdateTopicSettings(visible=True),
            },
        ),
    )
    camera = fl.ImagePanel(
        title="camera (annotated)",
        config=fl.ImageConfig(image_mode=fl.ImageModeConfig(image_topic=topic("foxglove/camera"))),
    )
    distance = fl.PlotPanel(
        title="end effector to target (m) and episode return",
        config=fl.PlotConfig(
            paths=[
                fl.PlotSeries(value=path("foxglove/distance", "distance"), label="distance m"),
                fl.PlotSeries(
                    value=path("telemetry/learner", "episode_return"), label="return", y_axis_id="ret"
                ),
            ],
            secondary_axes=[fl.PlotSecondaryAxis(id="ret", label="return")],
            show_legend=True,
        ),
    )
    retreat = fl.PlotPanel(
        title="retreat statistic at segment end vs threshold",
        config=fl.PlotConfig(
            paths=[
                fl.PlotSeries(
                    value=path("foxglove/retreat", "statistic"), label="statistic", show_line=False
                ),
                fl.PlotSeries(value=path("foxglove/retreat", "statistic_max"), label="peak", show_line=False),
                fl.PlotSeries(
                    value=path("foxglove/retreat", "threshold"), label="threshold", line_interpolation="step"
                ),
                fl.PlotSeries(value=path("events/retreat", "H"), label="H", y_axis_id="h", show_line=False),
            ],
            secondary_axes=[fl.PlotSecondaryAxis(id="h", label="H (steps)")],
            show_legend=True,
        ),
    )
    log = fl.LogPanel(title="safety events", config=fl.LogConfig(topic_to_render=topic("foxglove/log")))
    right = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(proportion=1.2, content=camera),
            fl.SplitItem(proportion=1, content=distance),
            fl.SplitItem(proportion=1, content=retreat),
            fl.SplitItem(proportion=0.8, content=log),
        ],
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[fl.SplitItem(proportion=1.4, content=scene), fl.SplitItem(proportion=1, content=right)],
        )
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--name", default="panda", help="the stack's name (adaptiveh/<name>/...)")
    p.add_argument("--out", default="configs/foxglove_layout.json")
    args = p.parse_args()
    text = json.dumps(json.loads(layout(args.name).to_json()), indent=1) + "\n"
    Path(args.out).write_text(text)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
