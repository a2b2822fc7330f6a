"""The Foxglove layout for flight records, built with Foxglove's SDK (``foxglove.layouts``).

``python -m quadnav_onboard.review.layout OUT.json`` writes it in the form Foxglove's app
imports (Layouts -> Import from file: ``configById`` and a ``layout`` tree of splits, the panels'
configurations as the SDK writes them); ``--sdk`` writes the SDK's own form instead. The copy
shipped in the docs is ``docs/foxglove-layout.json`` (docs/review.md says how to open a record
with it). Panels: the 3-D
scene (world, mission, primitives, vehicle and camera frames, setpoints), the depth image with its
calibration, the network input, the Q-values, position and decision plots, the mode and armed
timeline, the step record and the log.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import foxglove.layouts as fl

from quadnav_onboard.record.schemas import TOPICS

__all__ = ["app_layout", "flight_layout", "layout_topics", "main"]

_N_ACTIONS = 18


def _visible(*topics: str) -> dict[str, fl.BaseRendererBaseSettings]:
    return {t: fl.BaseRendererBaseSettings(visible=True) for t in topics}


def _three_d() -> fl.ThreeDeePanel:
    topics: dict[str, fl.BaseRendererTopicSettings] = {
        **_visible("/scene/world", "/scene/mission", "/planner/primitives", "/planner/path"),
        "/odometry": fl.BaseRendererPoseTopicSettings(visible=False),
        "/setpoint": fl.BaseRendererPoseTopicSettings(visible=True, type="arrow", color="#f28e2bff"),
    }
    return fl.ThreeDeePanel(
        title="3-D: world, mission, primitives (green allowed, red vetoed, white chosen)",
        config=fl.ThreeDeeConfig(follow_tf="body", topics=topics),
    )


def _plot(title: str, series: list[tuple[str, str]]) -> fl.PlotPanel:
    paths = [fl.PlotSeries(value=v, label=label, timestamp_method="receiveTime") for v, label in series]
    return fl.PlotPanel(title=title, config=fl.PlotConfig(paths=paths, show_legend=True))


def flight_layout() -> fl.Layout:
    """The layout: 3-D and images on the left, plots on the right, log and step record below."""
    q_values = [(f"/planner/step.q_values[{a}]", f"Q{a}") for a in range(_N_ACTIONS)]
    position = [(f"/odometry.pose.position.{c}", f"flown {c}") for c in "xyz"] + [
        (f"/setpoint.pose.position.{c}", f"commanded {c}") for c in "xyz"
    ]
    decisions = [
        ("/planner/step.action", "action"),
        ("/planner/step.reward", "reward"),
        ("/planner/step.deviation_m", "deviation (m)"),
        ("/planner/step.latency_ms", "latency (ms)"),
    ]
    depth = fl.ImagePanel(
        title="Depth camera (mm)",
        config=fl.ImageConfig(image_mode=fl.ImageModeConfig(
            image_topic="/camera/depth", calibration_topic="/camera/depth/calibration",
            color_mode="colormap", color_map="turbo",
        )),
    )
    net_input = fl.ImagePanel(
        title="Network input (32x32)",
        config=fl.ImageConfig(image_mode=fl.ImageModeConfig(image_topic="/planner/input")),
    )
    modes = fl.StateTransitionsPanel(
        title="Mode and armed",
        config=fl.StateTransitionsConfig(paths=[
            fl.StateTransitionsSeries(value="/vehicle.mode", label="mode", timestamp_method="receiveTime"),
            fl.StateTransitionsSeries(value="/vehicle.armed", label="armed", timestamp_method="receiveTime"),
        ]),
    )
    left = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=3, content=_three_d()),
        fl.SplitItem(proportion=2, content=fl.SplitContainer(direction="row", items=[
            fl.SplitItem(proportion=2, content=depth),
            fl.SplitItem(proportion=1, content=net_input),
        ])),
    ])
    right = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(content=_plot("Q-values per decision", q_values)),
        fl.SplitItem(content=_plot("Position: flown and commanded (world, m)", position)),
        fl.SplitItem(content=_plot("Decisions", decisions)),
        fl.SplitItem(content=modes),
    ])
    bottom = fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=2, content=fl.LogPanel(
            title="Events", config=fl.LogConfig(topic_to_render="/events")
        )),
        fl.SplitItem(content=fl.RawMessagesPanel(
            title="Step record", config=fl.RawMessagesConfig(topic_path="/planner/step")
        )),
    ])
    return fl.Layout(content=fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=4, content=fl.SplitContainer(direction="row", items=[
            fl.SplitItem(proportion=3, content=left), fl.SplitItem(proportion=2, content=right),
        ])),
        fl.SplitItem(proportion=1, content=bottom),
    ]))


def layout_topics(layout_json: str) -> set[str]:
    """Every record topic the layout's panels name (message paths reduced to their topic)."""
    found: set[str] = set()

    def walk(node: object) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                walk(k)
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)
        elif isinstance(node, str) and node.startswith("/"):
            found.add(node.split(".", 1)[0])

    walk(json.loads(layout_json))
    return found


_APP_PANEL_IDS = {"ThreeDee": "3D", "Log": "RosOut"}
"""The app's panel ids where they differ from the SDK's panel types."""


def app_layout(layout: fl.Layout) -> dict[str, Any]:
    """The SDK's layout in the form the app imports: each panel's configuration under
    ``configById`` (its title as ``foxglovePanelTitle``), splits as a binary ``layout`` tree."""
    config_by_id: dict[str, Any] = {}

    def node(content: dict[str, Any]) -> Any:
        if content["type"] == "panel":
            kind = _APP_PANEL_IDS.get(content["panelType"], content["panelType"])
            panel_id = f"{kind}!quadnav{len(config_by_id)}"
            config = dict(content.get("config") or {})
            if content.get("title"):
                config["foxglovePanelTitle"] = content["title"]
            config_by_id[panel_id] = config
            return panel_id
        if content["type"] != "split":
            raise ValueError(f"layout container {content['type']!r} has no app form here")
        return split(content["items"], content["direction"])

    def split(items: list[dict[str, Any]], direction: str) -> Any:
        if len(items) == 1:
            return node(items[0]["content"])
        first, total = items[0]["proportion"], sum(i["proportion"] for i in items)
        return {
            "first": node(items[0]["content"]),
            "second": split(items[1:], direction),
            "direction": direction,
            "splitPercentage": round(100.0 * first / total, 2),
        }

    tree = node(json.loads(layout.to_json())["content"])
    return {"configById": config_by_id, "globalVariables": {}, "userNodes": {},
            "playbackConfig": {"speed": 1.0}, "layout": tree}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m quadnav_onboard.review.layout", description=__doc__.splitlines()[0]
    )
    p.add_argument("out", type=Path, help="where to write the layout JSON")
    p.add_argument("--sdk", action="store_true", help="the SDK's own layout form, not the app's import form")
    args = p.parse_args(argv)
    layout = flight_layout()
    data = json.loads(layout.to_json()) if args.sdk else app_layout(layout)
    text = json.dumps(data, indent=1) + "\n"
    unknown = layout_topics(text) - set(TOPICS)
    if unknown:  # a panel naming a topic no record has
        print(f"layout names topics no record has: {sorted(unknown)}", file=sys.stderr)
        return 1
    args.out.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
