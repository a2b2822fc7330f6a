"""The Foxglove layout shipped with the docs: what the SDK builds, naming only record topics."""

from __future__ import annotations

import json
from pathlib import Path

from quadnav_onboard.record.schemas import TOPICS
from quadnav_onboard.review.layout import app_layout, flight_layout, layout_topics, main

SHIPPED = Path(__file__).resolve().parents[1] / "docs" / "foxglove-layout.json"


def test_the_shipped_layout_is_what_the_generator_writes(tmp_path):
    """docs/foxglove-layout.json is the generator's output as it stands (regenerate after a change)."""
    out = tmp_path / "layout.json"
    assert main([str(out)]) == 0
    assert json.loads(out.read_text()) == json.loads(SHIPPED.read_text())


def test_the_layout_names_only_record_topics_and_shows_the_3d_scene():
    """Every topic a panel names is one a record has; the 3-D scene, the depth image with its
    calibration, the Q-values, the vehicle's mode and the events all have a panel."""
    text = SHIPPED.read_text()
    named = layout_topics(text)
    assert named <= set(TOPICS)
    assert {"/scene/world", "/scene/mission", "/planner/primitives", "/camera/depth",
            "/camera/depth/calibration", "/planner/step", "/vehicle", "/events"} <= named
    kinds = {panel_id.split("!")[0] for panel_id in json.loads(text)["configById"]}
    assert {"3D", "Image", "Plot", "StateTransitions", "RosOut"} <= kinds


def test_every_panel_of_the_sdk_layout_is_in_the_app_form_once():
    """The app's form keeps each of the SDK's panels, with its configuration, exactly once."""
    sdk = json.loads(flight_layout().to_json())
    panels: list[dict] = []

    def walk(node: dict) -> None:
        if node["type"] == "panel":
            panels.append(node)
        else:
            for item in node["items"]:
                walk(item["content"])

    walk(sdk["content"])
    app = app_layout(flight_layout())
    leaves: list[str] = []

    def leaf(node: object) -> None:
        if isinstance(node, str):
            leaves.append(node)
        else:
            leaf(node["first"])  # type: ignore[index]
            leaf(node["second"])  # type: ignore[index]

    leaf(app["layout"])
    assert sorted(leaves) == sorted(app["configById"]) and len(leaves) == len(panels)
    titles = sorted(c["foxglovePanelTitle"] for c in app["configById"].values())
    assert titles == sorted(p["title"] for p in panels)
