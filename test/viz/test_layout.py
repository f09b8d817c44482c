"""The shipped Foxglove layout points at channels and fields the viz node really serves."""

from __future__ import annotations

import json
import re
from pathlib import Path

from sdhn_base.ros.topics import VIZ_EPISODES, VIZ_HYPERGRAPH, VIZ_METRICS, VIZ_P_H, VIZ_SCENE
from sdhn_sim.viz.channels import EPISODE_SCHEMA, METRICS_SCHEMA

LAYOUT = Path(__file__).resolve().parents[2] / "configs" / "foxglove" / "sdhn_layout.json"
FIELDS = {
    VIZ_METRICS: set(METRICS_SCHEMA["properties"]),
    VIZ_EPISODES: set(EPISODE_SCHEMA["properties"]),
}


def test_layout_references_served_topics_and_fields() -> None:
    text = LAYOUT.read_text()
    layout = json.loads(text)
    assert layout["version"] == 1
    served = {VIZ_SCENE, VIZ_HYPERGRAPH, VIZ_P_H, VIZ_METRICS, VIZ_EPISODES}
    used = set(re.findall(r'"(/viz/[a-z_/]+)', text))
    assert used and used <= served, used - served
    for topic, field in re.findall(r'"(/viz/[a-z_/]+)\.([a-z_]+)"', text):
        assert field in FIELDS[topic], f"{topic}.{field} is not in its schema"
    assert {VIZ_SCENE, VIZ_HYPERGRAPH, VIZ_P_H} <= used


def test_layout_shows_the_standard_topics() -> None:
    """Beside the viz channels, the layout shows the standard topics the nodes publish: every
    node's /diagnostics (a diagnostics panel) and the default team's robot poses in the 3D view."""
    from sdhn_base.ros.topics import DEFAULT_TEAM_NS, DIAGNOSTICS, POSES, absolute

    layout = json.loads(LAYOUT.read_text())
    panels: list[dict] = []

    def walk(node: dict) -> None:
        content = node.get("content", node)
        if content.get("type") == "panel":
            panels.append(content)
        for item in content.get("items", []):
            walk(item)

    walk(layout)
    diag = [p for p in panels if p["panelType"].startswith("Diagnostic")]
    assert [p["config"]["topicToRender"] for p in diag] == [DIAGNOSTICS], diag
    three = next(p for p in panels if p["panelType"] == "ThreeDee")
    assert absolute(DEFAULT_TEAM_NS, POSES) in three["config"]["topics"], three["config"]
