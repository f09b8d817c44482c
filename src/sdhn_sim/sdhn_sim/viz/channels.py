"""Viz channels for MCAP files and replay servers: Foxglove messages derived from team messages.

No ROS here: ``VizDeriver.derive(kind, msg, log_time_ns)`` takes a *decoded* TeamState /
Hypergraph / EpisodeSummary (kind ``state`` / ``hypergraph`` / ``episode``; the caller decodes the
CDR) and returns the encoded viz messages it produces, on the live node's channels:

    /viz/scene           foxglove.SceneUpdate (protobuf)   per state: map + robots, complete
    /viz/metrics         sdhn.VizMetrics (JSON)            per state
    /viz/hypergraph      foxglove.SceneUpdate (protobuf)   per hypergraph (once a state is known)
    /viz/hypergraph/p_h  foxglove.RawImage (protobuf)      per hypergraph
    /viz/episodes        sdhn.VizEpisode (JSON)            per episode summary

Every viz message gets the log time of the message it was derived from, so a viewer shows it at
the same instant as its source. ``VizMcapChannels`` writes them into an ``mcap.writer.Writer``
(schemas from the Foxglove messages' ``get_schema()``: encoding ``protobuf`` with a
FileDescriptorSet; ``jsonschema`` for the dict channels).

Unlike the live node, each recorded scene is complete (floor, obstacles, goals *and* robots): a
viewer that seeks in a file shows only the latest message of a topic, so a scene without the map
would show robots in the void. The static part is encoded once per (env, episode, map) and its
bytes prepended to each state's robots (protobuf: concatenated encodings of a message whose only
set field is repeated are the encoding of the concatenated list), so a state costs only the robots'
encoding.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass
from functools import cache
from typing import Any

from foxglove.messages import RawImage, SceneUpdate
from mcap.writer import Writer

from sdhn_base.ros.topics import VIZ_EPISODES, VIZ_HYPERGRAPH, VIZ_METRICS, VIZ_P_H, VIZ_SCENE
from sdhn_sim.viz.renderer import VizRenderer
from sdhn_sim.viz.world import BadInput

# The JSON channels' schemas (the protobuf ones come with the Foxglove messages).
METRICS_SCHEMA: dict[str, Any] = {
    "title": "sdhn.VizMetrics",
    "type": "object",
    "properties": {
        "env": {"type": "string"},
        "episode": {"type": "integer"},
        "step": {"type": "integer"},
        "step_rate": {"type": "number", "description": "team states per second (recent)"},
        "team_reward": {"type": "number"},
        "return_so_far": {"type": "number"},
        "makespan_so_far": {"type": "integer"},
        "missed_actions": {"type": "integer"},
        "last_return": {"type": ["number", "null"]},
        "last_makespan": {"type": ["integer", "null"], "description": "null = not completed"},
        "last_collisions": {"type": ["integer", "null"]},
        "episodes_done": {"type": "integer"},
        "policy_version": {"type": "integer", "description": "newest weights version seen"},
        "skewness": {"type": ["number", "null"]},
        "dropped": {"type": "integer", "description": "malformed input messages dropped"},
    },
}
EPISODE_SCHEMA: dict[str, Any] = {
    "title": "sdhn.VizEpisode",
    "type": "object",
    "properties": {
        "env": {"type": "string"},
        "episode": {"type": "integer"},
        "length": {"type": "integer"},
        "completed": {"type": "boolean"},
        "makespan": {"type": ["integer", "null"], "description": "null = not completed (NC)"},
        "episode_return": {"type": "number"},
        "collisions": {"type": "integer"},
        "formation_error": {"type": "number"},
        "missed_actions": {"type": "integer"},
        "policy_version": {"type": "integer"},
        "instance_id": {"type": "integer", "description": "MAIF instance; -1 = not known"},
    },
}


VIZ_TOPICS = (VIZ_SCENE, VIZ_HYPERGRAPH, VIZ_P_H, VIZ_METRICS, VIZ_EPISODES)
# ROS message type -> VizRenderer kind
KINDS = {
    "sdhn_msgs/msg/TeamState": "state",
    "sdhn_msgs/msg/Hypergraph": "hypergraph",
    "sdhn_msgs/msg/EpisodeSummary": "episode",
}


@dataclass(frozen=True)
class ChannelSpec:
    schema_name: str
    schema_encoding: str  # "protobuf" | "jsonschema"
    schema_data: bytes
    message_encoding: str  # "protobuf" | "json"


@cache
def channel_specs() -> dict[str, ChannelSpec]:
    """Topic -> schema and encodings, exactly as the live viz node advertises them."""

    def proto(cls: Any) -> ChannelSpec:
        s = cls.get_schema()
        return ChannelSpec(str(s.name), str(s.encoding), bytes(s.data), "protobuf")

    def js(schema: dict[str, Any]) -> ChannelSpec:
        return ChannelSpec(str(schema["title"]), "jsonschema", json.dumps(schema).encode(), "json")

    return {
        VIZ_SCENE: proto(SceneUpdate),
        VIZ_HYPERGRAPH: proto(SceneUpdate),
        VIZ_P_H: proto(RawImage),
        VIZ_METRICS: js(METRICS_SCHEMA),
        VIZ_EPISODES: js(EPISODE_SCHEMA),
    }


def is_viz_channel(topic: str, message_encoding: str) -> bool:
    """True for a viz channel (not the CDR team topics, which may share a suffix)."""
    return topic in VIZ_TOPICS and message_encoding in ("protobuf", "json")


@dataclass(frozen=True)
class VizMessage:
    topic: str
    data: bytes
    log_time_ns: int


def _json(d: dict[str, Any]) -> bytes:
    return json.dumps(d, separators=(",", ":")).encode()


class VizDeriver:
    """One renderer fed in message order; ``dropped`` counts messages that cannot be drawn."""

    def __init__(self, trail_length: int = 12) -> None:
        self.renderer = VizRenderer(env="", trail_length=trail_length)
        self.dropped: Counter[str] = Counter()
        self.written: Counter[str] = Counter()
        self._static_key: tuple[Any, ...] | None = None
        self._static: bytes = b""

    def derive(self, kind: str, msg: Any, log_time_ns: int) -> list[VizMessage]:
        try:
            out = self._derive(kind, msg)
        except BadInput as error:
            self.dropped[f"{kind}/{error.kind}"] += 1
            self.renderer.dropped += 1
            return []
        for topic, _ in out:
            self.written[topic] += 1
        return [VizMessage(topic, data, log_time_ns) for topic, data in out]

    def _derive(self, kind: str, msg: Any) -> list[tuple[str, bytes]]:
        r = self.renderer
        if kind == "state":
            # the step rate in the metrics comes from the states' header stamps, as in render()
            frame = r.on_state(msg)
            return [(VIZ_SCENE, self._scene_bytes(frame)), (VIZ_METRICS, _json(r.metrics()))]
        if kind == "hypergraph":
            r.on_hypergraph(msg)
            out: list[tuple[str, bytes]] = []
            scene = r.hypergraph_scene()
            if scene is not None:
                out.append((VIZ_HYPERGRAPH, scene.encode()))
            image = r.p_h_image()
            if image is not None:
                out.append((VIZ_P_H, image.encode()))
            return out
        if kind == "episode":
            return [(VIZ_EPISODES, _json(r.on_episode(msg)))]
        raise ValueError(f"kind must be state, hypergraph or episode, got {kind!r}")

    def _scene_bytes(self, frame: Any) -> bytes:
        r = self.renderer
        estimate = r.map_estimate()
        key = None if estimate is not None and not estimate.exact else (
            frame.env_name, frame.episode, -1 if estimate is None else estimate.instance_id)
        robots = r.scene(with_static=False).encode()
        if key is None or key != self._static_key:
            full = r.scene(with_static=True).encode()
            if key is None or not full.endswith(robots):
                self._static_key = None  # map still being discovered: never reuse it
                return full
            self._static_key, self._static = key, full[: len(full) - len(robots)]
        return self._static + robots


class VizMcapChannels:
    """Registers the viz schemas/channels on first use and writes VizMessages into ``writer``."""

    def __init__(self, writer: Writer) -> None:
        self.writer = writer
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._sequence: Counter[str] = Counter()

    def _channel(self, topic: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            spec = channel_specs()[topic]
            schema = self._schemas.get(spec.schema_name)
            if schema is None:
                schema = self.writer.register_schema(
                    name=spec.schema_name, encoding=spec.schema_encoding, data=spec.schema_data)
                self._schemas[spec.schema_name] = schema
            channel = self.writer.register_channel(
                topic=topic, message_encoding=spec.message_encoding, schema_id=schema)
            self._channels[topic] = channel
        return channel

    def write(self, messages: list[VizMessage]) -> None:
        for m in messages:
            self.writer.add_message(channel_id=self._channel(m.topic), log_time=m.log_time_ns,
                                    publish_time=m.log_time_ns, data=m.data,
                                    sequence=self._sequence[m.topic])
            self._sequence[m.topic] += 1
