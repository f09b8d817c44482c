"""The shipped Foxglove layout points at channels and fields the viz node really serves."""

from __future__ import annotations

import json
import re
from pathlib import Path

from sdhn_sim.ros.topics import VIZ_EPISODES, VIZ_HYPERGRAPH, VIZ_METRICS, VIZ_P_H, VIZ_SCENE
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
