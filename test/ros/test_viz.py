"""``sdhn_sim viz`` as a real process: rclpy publishers in this test, a ``websockets`` client
speaking the Foxglove WebSocket protocol, protobuf decoding with the advertised descriptors."""

from __future__ import annotations

import array
import asyncio
import base64
import contextlib
import json
import os
import re
import socket
import struct
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
import websockets
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from rclpy.context import Context

from sdhn_base.ros import topics
from sdhn_base.ros.qos import SENSOR, STEP
from sdhn_msgs.msg import EpisodeSummary, Hypergraph, TeamState
from sdhn_sim.envs import make_single_env
from sdhn_sim.viz.draw import map_to_cell

from .processes import ROS2, NodeProcess, node_processes

pytestmark = pytest.mark.ros

ENV = "maif-tiny"
# The viz server (the Foxglove SDK's) accepts foxglove.sdk.v1; offer both, as the Foxglove app
# does.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def viz_command(*params: str) -> list[str]:
    args = ["-p", "port:=0", "-p", "max_rate:=0"]
    for p in params:
        args += ["-p", p]
    return [*ROS2, "run", "sdhn_sim", "viz", "--ros-args", *args]


def served_port(node: NodeProcess) -> int:
    assert node.wait_for_line("ready", timeout=30), f"viz never ready:\n{node.output}"
    found = re.search(r"ws://[^:]+:(\d+)", node.output)
    assert found, node.output
    return int(found.group(1))


class TeamPublisher:
    """rclpy publishers of the team topics, from this test process."""

    def __init__(self) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("viz_test_publisher", context=self.context)
        def name(relative: str) -> str:
            return topics.absolute("/sdhn", relative)

        self.state = self.node.create_publisher(TeamState, name(topics.STATE), STEP)
        self.hyper = self.node.create_publisher(Hypergraph, name(topics.HYPERGRAPH), SENSOR)
        self.episode = self.node.create_publisher(EpisodeSummary, name(topics.EPISODE), STEP)
        env = make_single_env(ENV, seed=5)
        _, state = env.reset()
        self.positions = env.positions.copy()
        self.state_values = state.astype(np.float32)

    def wait_matched(self, timeout: float = 20.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            pubs = (self.state, self.hyper, self.episode)
            if all(p.get_subscription_count() > 0 for p in pubs):
                return
            time.sleep(0.05)
        raise AssertionError("viz never subscribed to state, hypergraph and episode")

    def team_state(self, step: int, env_name: str = ENV, size: int | None = None) -> TeamState:
        values = self.state_values if size is None else np.zeros(size, np.float32)
        msg = TeamState(env_name=env_name, episode=0, step=step, num_robots=4)
        msg.state = array.array("f", values.tobytes())
        msg.positions = array.array("i", self.positions.reshape(-1).astype(np.int32).tobytes())
        return msg

    def hypergraph(self) -> Hypergraph:
        p_h = np.array([[0.9, 0.1], [0.8, 0.2], [0.1, 0.7], [0.2, 0.95]], np.float32)
        msg = Hypergraph(num_robots=4, num_hyperedges=2, skewness=0.125, policy_version=2)
        msg.p_h = array.array("f", p_h.tobytes())
        msg.incidence = (p_h > 0.5).astype(np.uint8).tobytes()
        return msg

    @contextmanager
    def publishing(self, period: float = 0.03) -> Iterator[None]:
        """Keep publishing valid states (and hypergraphs) in the background."""
        stop = threading.Event()

        def loop() -> None:
            step = 0
            while not stop.is_set():
                self.state.publish(self.team_state(step))
                self.hyper.publish(self.hypergraph())
                step += 1
                stop.wait(period)

        thread = threading.Thread(target=loop, daemon=True)
        thread.start()
        try:
            yield
        finally:
            stop.set()
            thread.join()

    def close(self) -> None:
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def team() -> Iterator[TeamPublisher]:
    pub = TeamPublisher()
    try:
        yield pub
    finally:
        pub.close()


def message_class(channel: dict[str, Any]) -> Any:
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


class FoxgloveClient:
    """Minimal foxglove.websocket.v1 client: advertisements, subscriptions, message data."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.channels: dict[str, dict[str, Any]] = {}
        self.by_sub: dict[int, str] = {}

    async def read_advertisements(self, topics: set[str], timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        while not topics <= set(self.channels):
            left = deadline - time.monotonic()
            assert left > 0, f"advertised only {sorted(self.channels)}"
            raw = await asyncio.wait_for(self.ws.recv(), left)
            if isinstance(raw, str):
                op = json.loads(raw)
                if op["op"] == "advertise":
                    self.channels.update({c["topic"]: c for c in op["channels"]})

    async def subscribe(self, *topics: str) -> None:
        subs = []
        for topic in topics:
            sub_id = len(self.by_sub) + 1
            self.by_sub[sub_id] = topic
            subs.append({"id": sub_id, "channelId": self.channels[topic]["id"]})
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def next_on(self, topic: str, timeout: float = 10.0) -> bytes:
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            assert left > 0, f"no message on {topic}"
            raw = await asyncio.wait_for(self.ws.recv(), left)
            if isinstance(raw, bytes) and raw[0] == 1:
                sub_id, _log_time = struct.unpack_from("<IQ", raw, 1)
                if self.by_sub.get(sub_id) == topic:
                    return raw[13:]


TOPICS = {
    "/viz/scene": "foxglove.SceneUpdate",
    "/viz/hypergraph": "foxglove.SceneUpdate",
    "/viz/hypergraph/p_h": "foxglove.RawImage",
    "/viz/metrics": "sdhn.VizMetrics",
    "/viz/episodes": "sdhn.VizEpisode",
}


def test_viz_serves_robots_at_the_state_cells_and_survives_bad_input(team: TeamPublisher) -> None:
    with node_processes(viz_command(f"env:={ENV}")) as (viz,):
        port = served_port(viz)
        team.wait_matched()
        team.state.publish(team.team_state(0, size=7))  # wrong size
        team.state.publish(team.team_state(0, env_name="maif-nope"))  # unknown env
        assert viz.wait_for_line("dropped state: wrong_state_length", 10), viz.output

        async def watch() -> tuple[Any, Any, Any, dict[str, Any]]:
            async with websockets.connect(
                f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS, proxy=None
            ) as ws:
                client = FoxgloveClient(ws)
                await client.read_advertisements(set(TOPICS))
                for topic, schema_name in TOPICS.items():
                    assert client.channels[topic]["schemaName"] == schema_name, topic
                await client.subscribe(*TOPICS)
                with team.publishing():
                    scene = message_class(client.channels["/viz/scene"]).FromString(
                        await client.next_on("/viz/scene")
                    )
                    hyper = message_class(client.channels["/viz/hypergraph"]).FromString(
                        await client.next_on("/viz/hypergraph")
                    )
                    image = message_class(client.channels["/viz/hypergraph/p_h"]).FromString(
                        await client.next_on("/viz/hypergraph/p_h")
                    )
                    metrics = json.loads(await client.next_on("/viz/metrics"))
                return scene, hyper, image, metrics

        scene, hyper, image, metrics = asyncio.run(watch())
        code = viz.stop()
    robots = {e.id: e for e in scene.entities if e.id.startswith("robot/")}
    assert len(robots) == 4, [e.id for e in scene.entities]
    for i, (x, y) in enumerate(team.positions.tolist()):
        p = robots[f"robot/{i}"].cubes[0].pose.position
        assert robots[f"robot/{i}"].frame_id == "map"
        assert map_to_cell(p.x, p.y) == (x, y), f"robot {i} drawn at {p.x},{p.y}, state ({x},{y})"
    assert any(e.id == "map/obstacles" for e in scene.entities), "first scene carries the map"
    edges = {e.id: e for e in hyper.entities}
    assert {"hypergraph", "hyperedge/0", "hyperedge/1"} <= set(edges)
    assert {kv.key: kv.value for kv in edges["hypergraph"].metadata}["skewness"] == "0.1250"
    assert (image.height, image.width, image.encoding) == (4 * 12, 2 * 12, "rgb8")
    assert metrics["env"] == ENV and metrics["dropped"] == 2, metrics
    assert code == 0, viz.output
    assert "state/unknown_env=1" in viz.output and "state/wrong_state_length=1" in viz.output


def test_viz_encodes_nothing_without_a_client(team: TeamPublisher) -> None:
    with node_processes(viz_command()) as (viz,):
        served_port(viz)
        team.wait_matched()
        for step in range(30):
            team.state.publish(team.team_state(step))
            team.hyper.publish(team.hypergraph())
        team.state.publish(team.team_state(30, size=3))  # in order after the 30: marks the end
        assert viz.wait_for_line("dropped state", 10), viz.output
        code = viz.stop()
    assert code == 0, viz.output
    assert "served 0 encoded messages" in viz.output, viz.output


CONFIG_ERRORS = {"port_in_use": "port:", "unknown_env": "env:",
                 "foreign_host": "host:"}  # an address not this machine's was named as port


@pytest.mark.parametrize("case", list(CONFIG_ERRORS))
def test_viz_config_errors_exit_2_with_one_line(case: str) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        params = {"port_in_use": [f"port:={port}"], "unknown_env": ["env:=maif-nope"],
                  "foreign_host": ["host:=203.0.113.7", "port:=0"]}[case]
        command = [*ROS2, "run", "sdhn_sim", "viz", "--ros-args"]
        for p in params:
            command += ["-p", p]
        with node_processes(command) as (viz,):
            viz.proc.wait(timeout=30)
            viz.stop()
    errors = [line for line in viz.lines if "error" in line]
    assert viz.proc.returncode == 2, viz.output
    assert len(errors) == 1, viz.output
    assert CONFIG_ERRORS[case] in errors[0], errors[0]
    if case == "port_in_use":
        assert str(port) in errors[0], errors[0]


def upgraded_socket(port: int) -> socket.socket:
    """A raw WebSocket client (zero mask) that subscribes to channel 1 and then never reads."""
    s = socket.create_connection(("127.0.0.1", port), timeout=5)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall(f"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
              f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
              "Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n".encode())
    assert b" 101 " in s.recv(200)
    return s


def send_text(s: socket.socket, text: str) -> None:
    payload = text.encode()
    assert len(payload) < 126
    s.sendall(bytes([0x81, 0x80 | len(payload)]) + b"\0\0\0\0" + payload)


def test_viz_survives_hostile_clients_logs_who_connects_and_stops_past_them(
        team: TeamPublisher) -> None:
    """Issue 54 items 1-2 on the node: a subscription id past uint32 killed the viz node from
    its ROS callback (FATAL); clients that never read held SIGINT for 70-100 s. Each client is
    logged with its address."""
    with node_processes(viz_command()) as (viz,):
        port = served_port(viz)
        team.wait_matched()
        hogs = [upgraded_socket(port) for _ in range(3)]
        for s in hogs:
            send_text(s, '{"op":"subscribe","subscriptions":[{"id":1,"channelId":1}]}')
        send_text(hogs[0], '{"op":"subscribe","subscriptions":[{"id":4294967296,"channelId":2}]}')
        assert viz.wait_for_line("Registered client 127.0.0.1", 10), viz.output

        async def watch() -> int:
            async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS,
                                          proxy=None) as ws:
                client = FoxgloveClient(ws)
                await client.read_advertisements(set(TOPICS))
                await client.subscribe("/viz/metrics")
                seen = 0
                with team.publishing(period=0.01):
                    for _ in range(20):
                        json.loads(await client.next_on("/viz/metrics"))
                        seen += 1
                return seen

        assert asyncio.run(watch()) == 20
        assert viz.proc.poll() is None, viz.output
        try:
            code = viz.stop(timeout=20)
        finally:
            for s in hogs:
                s.close()
    assert code == 0, viz.where() if code is None else viz.output
    assert "4294967296" in viz.output, viz.output  # the SDK's refusal, in the node's log


def listening_tcp_ports(pid: int) -> set[int]:
    """TCP ports the process ``pid`` listens on (its socket inodes in /proc/net/tcp{,6})."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with contextlib.suppress(OSError):
            target = os.readlink(fd)
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    ports = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with contextlib.suppress(OSError):
            for line in Path(table).read_text().splitlines()[1:]:
                fields = line.split()
                if fields[3] == "0A" and fields[9] in inodes:  # state LISTEN
                    ports.add(int(fields[1].rsplit(":", 1)[1], 16))
    return ports


def test_viz_listens_only_on_the_served_port() -> None:
    """A gate in front of the SDK once left a second loopback port listening, unlogged. One
    listening socket, the served one."""
    node = NodeProcess(viz_command())
    try:
        port = served_port(node)
        ports = listening_tcp_ports(node.proc.pid)
        assert ports == {port}, f"viz listens on {sorted(ports)}, serves only {port}"
    finally:
        assert node.stop() == 0, node.output
