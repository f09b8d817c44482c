"""Recordings open as pictures: the recorder (real simulator + 4 actor processes on maif-tiny)
writes the viz channels beside the CDR topics, every protobuf message decodes with the schema's
own FileDescriptorSet and draws the robots where the recorded TeamState has them; a viz:=false
recording of the same run gains equal channels through ``replay --add-viz``; ``replay
--foxglove`` serves a recording to a Foxglove WebSocket client; a truncated recording upgrades up
to its last complete chunk with one line."""

from __future__ import annotations

import asyncio
import json
import re
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import websockets
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

from sdhn_base.ros.qos import SENSOR
from sdhn_msgs.msg import Hypergraph
from sdhn_policy.weights import ActorSpec, encode_actor, save_actor_file
from sdhn_sim.envs import make_single_env
from sdhn_sim.recording.reader import decode, read_recording
from sdhn_sim.recording.writer import McapRosWriter
from sdhn_sim.viz.draw import map_to_cell

from .deploy_helpers import TEAM_NS, actor_cmd, sim_cmd
from .own_node import own_node
from .processes import ROS2, node_processes
from .team_stream import ENV, hypergraph_message, team_stream
from .test_viz import SUBPROTOCOLS, TOPICS, FoxgloveClient
from .test_viz import message_class as ws_message_class

pytestmark = pytest.mark.ros

N, EPISODES, MAX_STEPS = 4, 2, 16
REPLAY = [*ROS2, "run", "sdhn_sim", "replay"]
PROTO_TOPICS = ("/viz/scene", "/viz/hypergraph", "/viz/hypergraph/p_h")


def random_actor(path: Path) -> Path:
    """NumPy-initialised actor weights (no training, no torch): the actors only need to answer."""
    env = make_single_env(ENV, seed=0)
    spec = ActorSpec(obs_size=env.obs_size, num_actions=env.num_actions, hidden_sizes=(16,),
                     gru_hidden=16)
    rng = np.random.default_rng(0)
    tensors = {k: rng.normal(0, 0.1, s).astype(np.float32)
               for k, s in spec.tensor_shapes().items()}
    save_actor_file(path, encode_actor(spec, tensors, version=1))
    return path


@dataclass
class Run:
    viz: Path  # recorded with viz:=true
    plain: Path  # the same run, recorded with viz:=false
    recorder_lines: list[str]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Run]:
    """Simulator + 4 actors (one process each), two recorders, hypergraphs from this process
    standing in for the trainer's."""
    root = tmp_path_factory.mktemp("vizrec")
    weights = random_actor(root / "actor.safetensors")
    viz, plain = root / "viz.mcap", root / "plain.mcap"
    recorders = [[*ROS2, "run", "sdhn_sim", "recorder", "--ros-args", "-p", f"output:={out}",
                  "-p", f"team_ns:={TEAM_NS}", *extra]
                 for out, extra in ((viz, ["-p", "viz:=true"]), (plain, ["-p", "viz:=false"]))]
    # action readers: the simulator and both recorders (each actor holds its obs subscription
    # until its action writer has matched all three)
    actors = [actor_cmd(i, N, weights_file=weights, seed=i, action_readers=3)
              for i in range(N)]
    with own_node("vizrec_hypergraphs") as node:
        # The trainer's profile: best effort, so a sample published before a recorder's reader has
        # matched this writer is simply not delivered to it (nothing is re-sent).
        graphs = node.create_publisher(Hypergraph, f"{TEAM_NS}/hypergraph", SENSOR)
        stop = threading.Event()

        def publish_graphs() -> None:
            k = 0
            while not stop.wait(0.02):
                graphs.publish(hypergraph_message(k))
                k += 1

        try:
            with node_processes(*recorders, *actors) as procs:
                for p in procs:
                    assert p.wait_for_line("ready", timeout=30), p.output
                # A recorder being ready says nothing about this process's writer: the sim only
                # waits for the recorders' obs/state subscriptions, and its run can be over before
                # the hypergraph writer and the recorders' best-effort readers have discovered
                # each other. Start the run only once both recorders are matched.
                deadline = time.monotonic() + 30
                while graphs.get_subscription_count() < 2 and time.monotonic() < deadline:
                    time.sleep(0.02)
                assert graphs.get_subscription_count() >= 2, (
                    f"hypergraph writer matched {graphs.get_subscription_count()} of 2 recorders")
                thread = threading.Thread(target=publish_graphs, daemon=True)
                thread.start()
                # both recorders must see every obs and state before step 0 (extra_subscribers=2)
                sim = sim_cmd(episodes=EPISODES, max_steps=MAX_STEPS, seed=3, extra_subscribers=2)
                with node_processes(sim) as (simp,):
                    assert simp.proc.wait(timeout=60) == 0, simp.output
                stop.set()
                thread.join()
                time.sleep(0.3)
                for rec in procs[:2]:
                    assert rec.stop(timeout=10.0) == 0, rec.output
                lines = [line for rec in procs[:2] for line in rec.lines
                         if "]: closed" in line or "]: viz:" in line]
                print("\n".join(lines))
        finally:
            stop.set()
    yield Run(viz, plain, lines)


def proto_class(schema_name: str, fds: bytes) -> Any:
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(fds).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def read_indexed(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """Every message through the summary/index (as Foxglove opens a file), decoded: protobuf with
    the schema's FileDescriptorSet, JSON, CDR; per topic, as (log time, message)."""
    out: dict[str, list[tuple[int, Any]]] = {}
    classes: dict[int, Any] = {}
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes, f"{path} has no index"
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.message_encoding == "protobuf":
                assert schema is not None and schema.encoding == "protobuf"
                if schema.id not in classes:
                    classes[schema.id] = proto_class(schema.name, schema.data)
                value = classes[schema.id].FromString(message.data)
            elif channel.message_encoding == "json":
                assert schema is not None and schema.encoding == "jsonschema"
                value = json.loads(message.data)
            else:
                assert schema is not None and schema.encoding == "ros2msg"
                value = message.data
            out.setdefault(channel.topic, []).append((message.log_time, value))
    return out


def state_keys(path: Path) -> tuple[dict[int, tuple[int, int]], dict[tuple[int, int], Any]]:
    """(log time -> (episode, step), (episode, step) -> TeamState) of the recorded states."""
    by_time, states = {}, {}
    for raw, s in read_recording(path).decoded(f"{TEAM_NS}/state"):
        by_time[raw.log_time_ns] = (int(s.episode), int(s.step))
        states[(int(s.episode), int(s.step))] = s
    return by_time, states


def scenes_by_step(path: Path) -> dict[tuple[int, int], Any]:
    by_time, _ = state_keys(path)
    return {by_time[t]: scene for t, scene in read_indexed(path)["/viz/scene"]}


def robot_cells(scene: Any) -> list[tuple[int, int]]:
    robots = sorted((e for e in scene.entities if e.id.startswith("robot/")),
                    key=lambda e: int(e.id.split("/")[1]))
    return [map_to_cell(e.cubes[0].pose.position.x, e.cubes[0].pose.position.y) for e in robots]


def test_recording_holds_viz_channels_that_draw_the_recorded_states(run: Run) -> None:
    topics = read_indexed(run.viz)
    schemas = {}
    with run.viz.open("rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        for ch in summary.channels.values():
            schemas[ch.topic] = summary.schemas[ch.schema_id].name
    for topic, name in TOPICS.items():
        if topic != "/viz/episodes" or EPISODES:
            assert schemas.get(topic) == name, (topic, schemas.get(topic))
    by_time, states = state_keys(run.viz)
    assert len(states) >= EPISODES * 2
    scenes = topics["/viz/scene"]
    assert len(scenes) == len(states) == len(topics["/viz/metrics"])
    for log_time, scene in scenes:
        key = by_time[log_time]  # each scene carries its state's log time
        want = np.frombuffer(states[key].positions, np.int32).reshape(-1, 2).tolist()
        assert robot_cells(scene) == [tuple(p) for p in want], key
        ids = {e.id for e in scene.entities}
        assert {"map/floor", "map/obstacles", "map/goals"} <= ids, "every scene is complete"
    assert len(topics["/viz/episodes"]) == len(topics[f"{TEAM_NS}/episode"]) == EPISODES
    assert topics["/viz/hypergraph"], "hypergraphs published during the run are drawn"
    for _, hyper in topics["/viz/hypergraph"]:
        assert {"hypergraph", "hyperedge/0"} <= {e.id for e in hyper.entities}
    for _, image in topics["/viz/hypergraph/p_h"]:
        assert (image.height, image.width, image.encoding) == (N * 12, 10 * 12, "rgb8")
    # the CDR part is what the viz:=false recorder got from the same run
    plain = read_recording(run.plain)
    assert [m.data for m in plain.messages if m.topic == f"{TEAM_NS}/state"] == [
        m.data for m in read_recording(run.viz).messages if m.topic == f"{TEAM_NS}/state"]
    assert not any(t.startswith("/viz/") for t in plain.topics())
    cost = [line for line in run.recorder_lines if "]: viz:" in line]
    assert len(cost) == 1 and "skipped (worker behind) 0" in cost[0], run.recorder_lines


def test_add_viz_upgrades_a_plain_recording_with_equal_scenes(run: Run) -> None:
    done = subprocess.run([*REPLAY, str(run.plain), "--add-viz"], capture_output=True, text=True,
                          timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    upgraded = run.plain.with_name("plain-viz.mcap")
    assert upgraded.is_file() and f"wrote {upgraded}" in done.stdout, done.stdout
    before, after = read_recording(run.plain), read_recording(upgraded)
    cdr = [(m.topic, m.log_time_ns, m.data) for m in after.messages if m.encoding == "cdr"]
    assert cdr == [(m.topic, m.log_time_ns, m.data) for m in before.messages]
    recorded, derived = scenes_by_step(run.viz), scenes_by_step(upgraded)
    assert recorded.keys() == derived.keys() and recorded
    for key, scene in recorded.items():  # (classes of two files' descriptor pools never ==)
        assert derived[key].SerializeToString(deterministic=True) == scene.SerializeToString(
            deterministic=True), f"scene of (episode, step) {key} differs"
    again = subprocess.run([*REPLAY, str(upgraded), "--add-viz"], capture_output=True, text=True,
                           timeout=60, check=False)
    assert again.returncode == 0, again.stderr
    assert "already has viz channels" in again.stdout and "nothing written" in again.stdout
    assert not upgraded.with_name("plain-viz-viz.mcap").exists()


def test_rate_republishes_only_the_ros_topics_of_a_viz_recording(run: Run) -> None:
    done = subprocess.run([*REPLAY, str(run.viz), "--rate", "100", "--wait", "0"],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    ros_topics = [t for t in read_recording(run.viz).topics() if not t.startswith("/viz/")]
    assert f"on {len(ros_topics)} topics" in done.stdout, done.stdout


def test_foxglove_serves_a_recording_and_a_busy_port_is_one_line(run: Run) -> None:
    _, states = state_keys(run.viz)
    first = np.frombuffer(states[min(states)].positions, np.int32).reshape(-1, 2).tolist()
    command = [*REPLAY, str(run.viz), "--foxglove", "--port", "0", "--rate", "4"]
    with node_processes(command) as (server,):
        assert server.wait_for_line("serving", timeout=30), server.output
        found = re.search(r"ws://[^:]+:(\d+)", server.output)
        assert found, server.output
        port = int(found.group(1))

        async def watch() -> Any:
            async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS,
                                          proxy=None) as ws:
                client = FoxgloveClient(ws)
                await client.read_advertisements(set(TOPICS))
                for topic, schema_name in TOPICS.items():
                    assert client.channels[topic]["schemaName"] == schema_name, topic
                await client.subscribe(*TOPICS)
                return ws_message_class(client.channels["/viz/scene"]).FromString(
                    await client.next_on("/viz/scene"))

        scene = asyncio.run(watch())
        assert robot_cells(scene) == [tuple(p) for p in first]
        assert server.stop(timeout=10.0) == 0, server.output
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        taken = busy.getsockname()[1]
        done = subprocess.run([*REPLAY, str(run.viz), "--foxglove", "--port", str(taken)],
                              capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and str(taken) in lines[0], lines


def test_truncated_recording_upgrades_up_to_its_last_chunk(tmp_path: Path) -> None:
    whole = tmp_path / "whole.mcap"
    with McapRosWriter(whole, chunk_bytes=8 * 1024) as writer:
        for k, o in enumerate(team_stream(3, 12)):
            writer.write(f"/sdhn/{o.topic}", o.message, log_time_ns=1_000_000 * (k + 1))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    readable = read_recording(cut)
    assert readable.truncated is not None and readable.messages
    out = tmp_path / "cut-upgraded.mcap"
    done = subprocess.run([*REPLAY, str(cut), "--add-viz", "--out", str(out)],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("replay: recording truncated after"), lines
    assert "last complete chunk at byte" in lines[0]
    upgraded = read_recording(out)
    assert upgraded.truncated is None
    assert [m.data for m in upgraded.messages if m.encoding == "cdr"] == [
        m.data for m in readable.messages]
    states = [decode(m) for m in readable.messages if m.topic == "/sdhn/state"]
    scenes = read_indexed(out)["/viz/scene"]
    assert len(scenes) == len(states)
    for (_, scene), state in zip(scenes, states, strict=True):
        want = np.frombuffer(state.positions, np.int32).reshape(-1, 2).tolist()
        assert robot_cells(scene) == [tuple(p) for p in want]
