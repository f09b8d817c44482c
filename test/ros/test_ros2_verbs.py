"""``ros2 topic|node|param|bag`` (our CLI, sdhn_bringup.ros2_*) against a live graph of real
processes: the simulator node (maif-tiny, waiting for actors that never come, so its graph and
parameters stay put) and a talker (graph_peer.py) that reports what it publishes and with which
QoS. Each verb's output is compared with what the node itself reports: the simulator's declared
parameters, the talker's QoS and sent messages, and, for bags, an independent read of the MCAP
file."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from sdhn_base.ros.graph import check_message_type
from sdhn_sim.recording.reader import decode, read_recording
from sdhn_sim.sim_node import PARAMETERS

from .deploy_helpers import sim_cmd
from .own_node import own_node_and_executor
from .processes import ROS2, NodeProcess, node_processes

NS = "/sdhn_cli"
PEER = [sys.executable, str(Path(__file__).with_name("graph_peer.py")), NS, "0.05"]
SIM = sim_cmd(ns=NS, step_deadline=0.5, seed=7, start_timeout=3600.0)
OBS = f"{NS}/peer/obs"
NOTE = f"{NS}/peer/note"


def ros2(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """One CLI call. Fast DDS's own log lines (colour-coded, e.g. a shared-memory port another
    process holds on a busy machine) go to stdout from C++, as with the real ros2; they are
    dropped here so the tool's own output is what is compared."""
    done = subprocess.run([*ROS2, *args], capture_output=True, text=True, timeout=timeout,
                          check=False)
    done.stdout = "".join(line for line in done.stdout.splitlines(keepends=True)
                          if not line.startswith("\x1b["))
    return done


def ros2_until(needles: str | tuple[str, ...], *args: str, timeout: float = 30.0) -> str:
    """The stdout of a CLI call, re-run until it holds every needle (discovery takes a moment,
    and without a daemon each call discovers the graph anew)."""
    end = time.monotonic() + timeout
    wanted = (needles,) if isinstance(needles, str) else needles
    while True:
        out = ros2(*args).stdout
        if all(n in out for n in wanted) or time.monotonic() > end:
            return out
        time.sleep(0.3)


@pytest.fixture(scope="module")
def graph() -> Iterator[tuple[NodeProcess, NodeProcess]]:
    with node_processes(PEER, SIM) as (peer, sim):
        assert peer.wait_for_line("SENT 3", 60), peer.output
        assert sim.proc.poll() is None, sim.output
        yield peer, sim
        peer.stop()
        sim.stop()


def peer_qos(peer: NodeProcess) -> dict[str, list[str]]:
    return {line.split()[1]: line.split()[2:] for line in peer.lines if line.startswith("QOS ")}


def test_topic_list_and_info_match_the_publishers(graph: Any) -> None:
    peer, _sim = graph
    listed = ros2_until((OBS, NOTE, f"{NS}/robot_0/obs"), "topic", "list", "-t")
    assert f"{OBS} [sdhn_msgs/msg/RobotObservation]" in listed.splitlines(), listed
    assert f"{NOTE} [std_msgs/msg/String]" in listed.splitlines(), listed
    assert f"{NS}/robot_0/obs [sdhn_msgs/msg/RobotObservation]" in listed.splitlines(), listed
    assert not any("_ros2cli" in line for line in listed.splitlines())
    # Every type this graph carries (ours, /rosout, /parameter_events, /diagnostics, poses) is
    # one that echo and hz accept: the allowlist of message packages covers the real graph.
    listed_types = {t.strip() for line in listed.splitlines()
                    for t in line.partition(" [")[2].rstrip("]").split(",")}
    assert {"rcl_interfaces/msg/Log", "geometry_msgs/msg/PoseArray"} <= listed_types, listed
    for type_name in listed_types:
        check_message_type(type_name)
    # -c counts what list prints (the graph is stable; a call may see it only partly at first).
    count = ros2_until(f"{len(listed.splitlines())}\n", "topic", "list", "-c")
    assert count.strip() == str(len(listed.splitlines())), (count, listed)
    for topic, (reliability, durability, _depth) in peer_qos(peer).items():
        out = ros2("topic", "info", topic, "-v").stdout
        assert "Publisher count: 1" in out, out
        assert "Node name: graph_peer" in out and f"Node namespace: {NS}" in out, out
        assert f"Reliability: {reliability}" in out and f"Durability: {durability}" in out, out
    unknown = ros2("topic", "info", f"{NS}/nothing")
    assert unknown.returncode == 1 and "Unknown topic" in unknown.stderr


def test_topic_echo_prints_the_sent_messages(graph: Any) -> None:
    peer, _sim = graph
    done = ros2("topic", "echo", OBS, "--once", "--full-length")
    assert done.returncode == 0, done.stderr
    doc = yaml.safe_load(done.stdout.split("---")[0])
    assert f"SENT {doc['step']}" in peer.lines, (doc["step"], peer.lines[-3:])
    expected = (doc["step"] + 0.25 * np.arange(57)).astype(np.float32)
    assert np.array_equal(np.asarray(doc["obs"], dtype=np.float32), expected)
    assert doc["reward"] == 0.5 and doc["header"]["frame_id"] == "", doc
    # Truncated as ros2cli does (arrays longer than --truncate-length end in '...').
    short = yaml.safe_load(ros2("topic", "echo", OBS, "--once", "-l", "4").stdout.split("---")[0])
    assert short["obs"][4] == "..." and len(short["obs"]) == 5, short["obs"]
    field = ros2("topic", "echo", OBS, "--once", "--field", "header.frame_id")
    assert field.returncode == 0 and field.stdout.strip().endswith("---"), field
    # Latched: the QoS chosen from the publisher (transient-local) receives the one old message.
    note = ros2("topic", "echo", NOTE, "--once")
    assert yaml.safe_load(note.stdout.split("---")[0]) == {"data": f"hello {NS}"}, note
    explicit = ros2("topic", "echo", NOTE, "--once", "--qos-durability", "transient_local",
                    "--qos-reliability", "reliable", "--qos-depth", "1")
    assert f"hello {NS}" in explicit.stdout, explicit


def test_topic_hz_reports_a_window_of_the_sent_messages(graph: Any) -> None:
    peer, _sim = graph
    hz = NodeProcess([*ROS2, "topic", "hz", OBS])
    try:
        assert hz.wait_for_line("window:", 60), hz.output
    finally:
        assert hz.stop(signal.SIGINT, 30) == 0, hz.output
    rate = next(float(line.split()[-1]) for line in hz.lines if line.startswith("average rate:"))
    window = max(int(line.split()[-1]) for line in hz.lines if "window:" in line)
    sent = sum(line.startswith("SENT ") for line in peer.lines)
    assert rate > 0 and 2 <= window <= sent, (rate, window, sent)


def test_node_list_and_info(graph: Any) -> None:
    names = ros2_until((f"{NS}/sim", f"{NS}/graph_peer"), "node", "list")
    assert {f"{NS}/sim", f"{NS}/graph_peer"} <= set(names.split()), names
    assert not any("_ros2cli" in n for n in names.split())
    assert "_ros2cli" in ros2("node", "list", "-a").stdout
    info = ros2("node", "info", f"{NS}/sim").stdout
    assert info.splitlines()[0] == f"{NS}/sim", info
    sections: dict[str, list[str]] = {}
    title = ""
    for line in info.splitlines()[1:]:
        if line.startswith("    "):
            sections[title].append(line.strip())
        elif line.strip():
            title = line.strip().rstrip(":")
            sections[title] = []
    assert list(sections) == ["Subscribers", "Publishers", "Service Servers", "Service Clients",
                              "Action Servers", "Action Clients"], info
    assert f"{NS}/robot_0/obs: sdhn_msgs/msg/RobotObservation" in sections["Publishers"], info
    assert f"{NS}/state: sdhn_msgs/msg/TeamState" in sections["Publishers"], info
    assert f"{NS}/robot_0/action: sdhn_msgs/msg/RobotAction" in sections["Subscribers"], info
    assert (f"{NS}/sim/get_parameters: rcl_interfaces/srv/GetParameters"
            in sections["Service Servers"]), info
    missing = ros2("node", "info", f"{NS}/nobody")
    assert missing.returncode == 1 and "Unable to find node" in missing.stderr


def test_param_list_get_set_dump_through_the_services(graph: Any) -> None:
    node = f"{NS}/sim"
    listed = ros2_until("env", "param", "list", node)
    names = {line.strip() for line in listed.splitlines()}
    assert set(PARAMETERS) <= names, (set(PARAMETERS) - names, listed)
    everyone = ros2_until((f"{node}:", f"{NS}/graph_peer:"), "param", "list")
    assert f"{node}:" in everyone.splitlines() and f"{NS}/graph_peer:" in everyone.splitlines()
    assert ros2("param", "get", node, "env").stdout.strip() == "String value is: maif-tiny"
    assert ros2("param", "get", node, "seed").stdout.strip() == "Integer value is: 7"
    assert ros2("param", "get", node, "step_deadline").stdout.strip() == "Double value is: 0.5"
    ok = ros2("param", "set", node, "step_deadline", "2.5")
    assert ok.returncode == 0 and ok.stdout.strip() == "Set parameter successful", ok
    assert ros2("param", "get", node, "step_deadline", "--hide-type").stdout.strip() == "2.5"
    # The node's descriptor refuses an out-of-range value and a wrong type; the value stays.
    bad = ros2("param", "set", node, "step_deadline", "99999.0")
    assert bad.returncode == 1 and bad.stderr.startswith("Set parameter failed"), bad
    wrong = ros2("param", "set", node, "seed", "abc")
    assert wrong.returncode == 1 and "Set parameter failed" in wrong.stderr, wrong
    dumped = yaml.safe_load(ros2("param", "dump", node).stdout)
    params = dumped[node]["ros__parameters"]
    assert params["env"] == "maif-tiny" and params["seed"] == 7, params
    assert params["step_deadline"] == 2.5 and set(PARAMETERS) <= set(params), params
    unset = ros2("param", "get", node, "no_such_parameter")
    assert unset.returncode == 1 and "Parameter not set" in unset.stdout


def test_bag_record_info_play(graph: Any, tmp_path: Path) -> None:
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

    bag = tmp_path / "bag"
    recorder = NodeProcess([*ROS2, "bag", "record", "-a", "-o", str(bag), "--team-ns", NS])
    try:
        # The recorder's first status line (5 s after start) says messages are coming in.
        assert recorder.wait_for_line("status:", 60), recorder.output
    finally:
        assert recorder.stop(signal.SIGINT, 30) == 0, recorder.output
    assert (bag / "metadata.yaml").is_file(), list(bag.iterdir())
    mcap_file = next(bag.glob("*.mcap"))
    rec = read_recording(mcap_file)
    counts = rec.topics()
    assert counts.get(OBS, 0) >= 2, counts

    for target in (bag, mcap_file):  # bag directory (metadata.yaml) and bare file (summary)
        out = ros2("bag", "info", str(target))
        assert out.returncode == 0, out.stderr
        lines = out.stdout.splitlines()
        assert f"Messages:          {sum(counts.values())}" in lines, out.stdout
        assert "Storage id:        mcap" in lines, out.stdout
        line = next(x for x in lines if f"Topic: {OBS} | Type:" in x)
        assert f"Type: sdhn_msgs/msg/RobotObservation | Count: {counts[OBS]} |" in line, line
        qos = next(x for x in lines if f"Topic: {OBS} | Offered:" in x)
        # As the talker offered it (history is not discovered for a topic outside the contract).
        reliability, durability, _depth = peer_qos(graph[0])[OBS]
        assert f"Offered: {reliability.lower()}, {durability.lower()}, " in qos, qos
        times = [m.log_time_ns for m in rec.messages]
        duration = (max(times) - min(times)) / 1e9
        shown = float(next(x for x in lines if x.startswith("Duration:")).split()[1].rstrip("s"))
        assert shown == pytest.approx(duration, abs=1e-9), (shown, duration)
    assert ros2("bag", "info", str(tmp_path / "none")).returncode == 2
    # A recorder killed mid-run leaves no summary: the readable messages are counted, and said so.
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(mcap_file.read_bytes()[: mcap_file.stat().st_size // 2])
    partial = ros2("bag", "info", str(cut))
    readable = len(read_recording(cut).messages)
    assert partial.returncode == 0 and f"Messages:          {readable}" in partial.stdout, partial
    assert "Note: no summary" in partial.stdout, partial.stdout

    # play: every recorded peer observation arrives, unchanged, with the recorded QoS.
    from rclpy.qos import QoSProfile
    from std_msgs.msg import String

    from sdhn_msgs.msg import RobotObservation

    got: list[Any] = []
    replay_ns = OBS  # played on the recorded name; the peer is stopped first so only the bag plays
    peer, _sim = graph
    with own_node_and_executor("bag_play_listener") as (node, executor):
        peer.stop()
        node.create_subscription(RobotObservation, replay_ns, got.append,
                                 QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.VOLATILE))
        node.create_subscription(String, NOTE, lambda _m: None,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        # -d: up to 60 s until both played topics have this listener (discovery on a busy machine)
        play = NodeProcess([*ROS2, "bag", "play", str(bag), "-r", "5", "-d", "60"])
        try:
            end = time.monotonic() + 120
            while play.proc.poll() is None and time.monotonic() < end:
                executor.spin_once(timeout_sec=0.05)
            for _ in range(20):
                executor.spin_once(timeout_sec=0.05)
        finally:
            play.stop()
    assert play.proc.returncode == 0, play.output
    recorded = [decode(m).step for m in rec.messages if m.topic == OBS]
    assert [m.step for m in got] == recorded, ([m.step for m in got][:5], recorded[:5])
