"""Write docs/foxglove-layout.json: panels configured with the official Foxglove SDK's
layout builder (``foxglove.layouts``), arranged in the layout file format that the Foxglove
app exports and imports (Layouts, "Import from file...": ``configById`` by ``Type!id``,
a ``layout`` tree of splits).

    python docs/make_foxglove_layout.py        (needs pip install 'hbvs[live]')

The layout shows a run file (or ``hbvs repeat --foxglove``): the camera image with the detected
(green) and desired (orange) points, the 3D scene (world, robot, camera, target, taught
path, true and taught poses), plots of e1, ebar2, e3 and dhat, and the event log. Topic
names come from hbvs_cli/io/topics.py.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import foxglove.layouts as fl

from hbvs_cli.io import topics

LAYOUT = Path(__file__).with_name("foxglove-layout.json")


def state(field: str) -> str:
    return f"{topics.STATE_TOPIC}.{field}"


def series(path: str, label: str) -> fl.PlotSeries:
    return fl.PlotSeries(value=path, label=label, enabled=True, timestamp_method="receiveTime")


def build() -> fl.Layout:
    image = fl.ImagePanel(
        title="camera",
        config=fl.ImageConfig(image_mode=fl.ImageModeConfig(
            image_topic=topics.IMAGE_TOPIC, calibration_topic=topics.CALIBRATION_TOPIC,
            annotations={topics.ANNOTATIONS_TOPIC: fl.ImageAnnotationSettings(visible=True)},
        )),
    )
    scene = fl.ThreeDeePanel(
        title="3D: world, robot, camera, target, taught path",
        config=fl.ThreeDeeConfig(
            fixed_frame="world", follow_tf="base_link", follow_mode="follow-position",
            topics={
                topics.SCENE_TOPIC: fl.BaseRendererSceneUpdateTopicSettings(visible=True),
                topics.TRUE_POSE_TOPIC: fl.BaseRendererPoseTopicSettings(visible=True),
                topics.DESIRED_POSE_TOPIC: fl.BaseRendererPoseTopicSettings(visible=True),
            },
        ),
    )
    errors = fl.PlotPanel(
        title="errors (19), (27)",
        config=fl.PlotConfig(paths=[
            series(state("e1"), "e1"), series(state("ebar2"), "ebar2"), series(state("e3"), "e3 (rad)"),
        ], show_legend=True),
    )
    depth = fl.PlotPanel(
        title="depth estimate dhat (31), m",
        config=fl.PlotConfig(paths=[series(state("dhat"), "dhat")], show_legend=True),
    )
    log = fl.LogPanel(title="events", config=fl.LogConfig(topic_to_render=topics.EVENTS_TOPIC))
    left = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=1, content=image), fl.SplitItem(proportion=1, content=scene),
    ])
    right = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=2, content=errors), fl.SplitItem(proportion=1, content=depth),
        fl.SplitItem(proportion=1, content=log),
    ])
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=1, content=left), fl.SplitItem(proportion=1, content=right),
    ]))


#: The app's panel type names (the ``Type`` of ``Type!id``) of the SDK's panel types.
APP_PANEL_TYPES = {"Image": "Image", "ThreeDee": "3D", "Plot": "Plot", "Log": "RosOut"}


def app_layout(sdk_layout: dict) -> dict:
    """The SDK's layout tree as the app's layout file: panels by id, binary splits."""
    config_by_id: dict = {}

    def tree(node: dict):
        if node.get("type") == "panel":
            panel_id = f"{APP_PANEL_TYPES[node['panelType']]}!{len(config_by_id) + 1}"
            config_by_id[panel_id] = node["config"] | {"foxglovePanelTitle": node["title"]}
            return panel_id
        items = node["items"]
        first, rest = items[0], items[1:]
        if not rest:
            return tree(first["content"])
        total = sum(item["proportion"] for item in items)
        second = tree(rest[0]["content"]) if len(rest) == 1 else tree({"direction": node["direction"], "items": rest})
        return {
            "direction": node["direction"], "first": tree(first["content"]), "second": second,
            "splitPercentage": round(100.0 * first["proportion"] / total, 6),
        }

    layout = tree(sdk_layout["content"])
    return {"configById": config_by_id, "globalVariables": {}, "userNodes": {}, "playbackConfig": {"speed": 1}, "layout": layout}


def layout_text() -> str:
    return json.dumps(app_layout(json.loads(build().to_json())), indent=2) + "\n"


if __name__ == "__main__":
    LAYOUT.write_text(layout_text())
    print(f"wrote {LAYOUT}", file=sys.stderr)
