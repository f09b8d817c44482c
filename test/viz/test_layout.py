"""The shipped Foxglove layout points at channels and fields the viz node really serves."""

from __future__ import annotations

import json
import re
from pathlib import Path

from sdhn_sim.viz.scene import (
    EPISODE_SCHEMA,
    METRICS_SCHEMA,
    TOPIC_EPISODES,
    TOPIC_HYPERGRAPH,
    TOPIC_METRICS,
    TOPIC_P_H,
    TOPIC_SCENE,
)

LAYOUT = Path(__file__).resolve().parents[2] / "configs" / "foxglove" / "sdhn_layout.json"
FIELDS = {
    TOPIC_METRICS: set(METRICS_SCHEMA["properties"]),
    TOPIC_EPISODES: set(EPISODE_SCHEMA["properties"]),
}


def test_layout_references_served_topics_and_fields() -> None:
    text = LAYOUT.read_text()
    layout = json.loads(text)
    assert layout["version"] == 1
    served = {TOPIC_SCENE, TOPIC_HYPERGRAPH, TOPIC_P_H, TOPIC_METRICS, TOPIC_EPISODES}
    used = set(re.findall(r'"(/viz/[a-z_/]+)', text))
    assert used and used <= served, used - served
    for topic, field in re.findall(r'"(/viz/[a-z_/]+)\.([a-z_]+)"', text):
        assert field in FIELDS[topic], f"{topic}.{field} is not in its schema"
    assert {TOPIC_SCENE, TOPIC_HYPERGRAPH, TOPIC_P_H} <= used
