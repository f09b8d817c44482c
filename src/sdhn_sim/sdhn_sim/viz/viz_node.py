"""Viz node: serves the team's state, hypergraphs and metrics to Foxglove over a WebSocket.

Subscribes to ``{team_ns}/state``, ``{team_ns}/hypergraph`` and ``{team_ns}/episode`` and serves a
Foxglove WebSocket (``sdhn_sim.viz.server``: the Foxglove SDK's server, loopback by default, its
client log passed to the node's log; protobuf ``foxglove.*`` schemas and JSON) with channels
``/viz/scene``, ``/viz/hypergraph`` (SceneUpdate), ``/viz/hypergraph/p_h`` (RawImage),
``/viz/metrics`` and ``/viz/episodes`` (JSON). Parsing, drawing and state live in ``world``,
``draw`` and ``renderer`` (ROS-free).

Nothing is built or encoded for a channel no client subscribes to (``VizServer.has_sinks``): the
callbacks only validate and keep a short trail. The scene is sent at most ``max_rate`` times per
second (a viewer cannot show more); the static part (floor, obstacles, goals) only when a client
subscribes, the episode or map changes, or every ``STATIC_PERIOD_S``.
"""

from __future__ import annotations

import ipaddress
import json
import time
from collections.abc import Sequence
from typing import Any

from rclpy.context import Context
from rclpy.node import Node

from sdhn_base.ros import topics
from sdhn_base.ros.params import any_number, declare, integer, string
from sdhn_base.ros.qos import SENSOR, STEP
from sdhn_base.ros.runner import ConfigError, run_node
from sdhn_base.ros.topics import VIZ_EPISODES, VIZ_HYPERGRAPH, VIZ_METRICS, VIZ_P_H, VIZ_SCENE
from sdhn_msgs.msg import EpisodeSummary, Hypergraph, TeamState
from sdhn_sim.envs.registry import env_names
from sdhn_sim.viz.renderer import VizRenderer
from sdhn_sim.viz.server import BindError, VizServer, ws_url
from sdhn_sim.viz.world import BadInput

STATIC_PERIOD_S = 5.0


def _check_params(team_ns: str, env: str, host: str) -> None:
    """What the descriptors cannot say: the namespace rule, a known env, a non-empty host."""
    topics.check_team_ns(team_ns)
    if env and env not in env_names():
        raise ConfigError(f"env: unknown environment {env!r}; allowed: '' (from messages), "
                          f"{', '.join(env_names())}")
    if not host:
        raise ConfigError("host: empty; allowed: an address or name, e.g. 127.0.0.1")


PARAMETERS = {
    "team_ns": (topics.DEFAULT_TEAM_NS, string(f"team namespace; {topics.TEAM_NS_RULE}")),
    "env": ("", string("environment to draw; '' = whatever the messages name")),
    "host": ("127.0.0.1", string("address the Foxglove WebSocket server binds")),
    "port": (8765, integer("Foxglove WebSocket port; 0 = any free port", 0, 65535)),
    "trail_length": (12, integer("steps of trail drawn behind each robot", 1, 10_000)),
}


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


class VizNode(Node):
    def __init__(self, context: Context) -> None:
        super().__init__("viz", context=context)
        p = declare(self, PARAMETERS)
        team_ns, env, host = str(p["team_ns"]), str(p["env"]), str(p["host"])
        port, trail = int(p["port"]), int(p["trail_length"])
        max_rate = self._rate("max_rate", 30.0)
        _check_params(team_ns, env, host)

        try:
            self.server = VizServer(host, port, "sdhn viz", self.get_logger().info)
        except BindError as error:
            raise ConfigError(f"{error.field}: {error.message}") from None

        self.renderer = VizRenderer(env=env, trail_length=trail)
        self.min_period = 1.0 / max_rate if max_rate > 0 else 0.0
        self.last_scene = 0.0
        self.last_static = 0.0
        self.static_key: tuple[str, int, int] | None = None
        self.dropped: dict[str, int] = {}
        self.encoded = 0

        ns = team_ns
        self.create_subscription(TeamState, topics.absolute(ns, topics.STATE), self.on_state,
                                 STEP)
        self.create_subscription(Hypergraph, topics.absolute(ns, topics.HYPERGRAPH),
                                 self.on_hypergraph, SENSOR)
        self.create_subscription(EpisodeSummary, topics.absolute(ns, topics.EPISODE),
                                 self.on_episode, STEP)
        if not _is_loopback(host):
            self.get_logger().warning(f"serving beyond loopback on {host}: anyone who can reach "
                                      "it can watch")
        self.get_logger().info(
            f"ready: foxglove {ws_url(host, self.server.port)} team_ns={ns} "
            f"env={env or '(from msgs)'}"
        )

    def _rate(self, name: str, default: float) -> float:
        """A rate in Hz that accepts 0 as well as 0.0 (dynamic typing: a double descriptor would
        refuse ``max_rate:=0``); anything but a number >= 0 is a ConfigError."""
        value = declare(self, {name: (default, any_number(
            "most scenes per second sent; 0 = every state",
            constraints="a number >= 0 Hz (0 = every state)"))})[name]
        if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0.0:
            raise ConfigError(f"{name}: {value!r}; allowed: a number >= 0 Hz (0 = every state)")
        return float(value)

    # -- input
    def drop(self, source: str, error: BadInput) -> None:
        key = f"{source}/{error.kind}"
        self.dropped[key] = self.dropped.get(key, 0) + 1
        self.renderer.dropped += 1
        if self.dropped[key] == 1:
            self.get_logger().warning(f"dropped {source}: {error} (counted as {key})")

    def on_state(self, msg: TeamState) -> None:
        now = time.monotonic()
        try:
            frame = self.renderer.on_state(msg, now_s=now)
        except BadInput as error:
            self.drop("state", error)
            return
        if now - self.last_scene < self.min_period:
            return
        self.last_scene = now
        if self.server.has_sinks(VIZ_SCENE):
            key = (frame.env_name, frame.episode, 0)
            estimate = self.renderer.map_estimate()
            exact = estimate is None or estimate.exact
            with_static = (
                key != self.static_key
                or not exact
                or self.server.new_subscriber.is_set()
                or now - self.last_static > STATIC_PERIOD_S
            )
            if with_static:
                self.server.new_subscriber.clear()
                self.static_key, self.last_static = key, now
            self.send(VIZ_SCENE, self.renderer.scene(with_static=with_static).encode())
        if self.server.has_sinks(VIZ_METRICS):
            self.send(VIZ_METRICS, _json(self.renderer.metrics()))

    def on_hypergraph(self, msg: Hypergraph) -> None:
        try:
            self.renderer.on_hypergraph(msg)
        except BadInput as error:
            self.drop("hypergraph", error)
            return
        if self.server.has_sinks(VIZ_HYPERGRAPH):
            scene = self.renderer.hypergraph_scene()
            if scene is not None:
                self.send(VIZ_HYPERGRAPH, scene.encode())
        if self.server.has_sinks(VIZ_P_H):
            image = self.renderer.p_h_image()
            if image is not None:
                self.send(VIZ_P_H, image.encode())

    def on_episode(self, msg: EpisodeSummary) -> None:
        try:
            summary = self.renderer.on_episode(msg)
        except BadInput as error:
            self.drop("episode", error)
            return
        if self.server.has_sinks(VIZ_EPISODES):
            self.server.log(VIZ_EPISODES, _json(summary), time.time_ns())

    def send(self, topic: str, data: bytes) -> None:
        self.server.log(topic, data, time.time_ns())
        self.encoded += 1

    def stop(self) -> None:
        self.server.close()
        dropped = ", ".join(f"{k}={v}" for k, v in sorted(self.dropped.items())) or "none"
        self.get_logger().info(f"served {self.encoded} encoded messages; dropped: {dropped}")


def _json(d: dict[str, Any]) -> bytes:
    return json.dumps(d, separators=(",", ":")).encode()


def _on_stop(node: Any) -> None:
    if isinstance(node, VizNode):
        node.stop()


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(lambda context, _args: VizNode(context), argv, on_stop=_on_stop)
