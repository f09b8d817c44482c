"""The recorder node writes every message of every topic under the team namespace (latched weights
included) into one MCAP file that rosbags opens; replay summarises it (the recomputed summary
equals the simulator's), renders frames, and reports a truncated file in one line."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
from rosbags.highlevel import AnyReader

from sdhn_base.ros import topics
from sdhn_base.ros.qos import LATCHED, SENSOR, STEP
from sdhn_sim.recording.reader import (
    read_recording,
    summaries_from_messages,
    summaries_from_states,
)
from sdhn_sim.recording.writer import McapRosWriter

from .own_node import own_node, own_node_and_executor
from .processes import ROS2, node_processes
from .team_stream import ENV, hypergraph_message, team_stream, weights_message

EPISODES, MAX_STEPS = 3, 12
REPLAY = [*ROS2, "run", "sdhn_sim", "replay"]


def expected_counts(ns: str) -> Counter[str]:
    return Counter(topics.absolute(ns, o.topic) for o in team_stream(EPISODES, MAX_STEPS))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, str]]:
    """Publish a 4-robot MAIF stream from this process while a recorder process records it."""
    out = tmp_path_factory.mktemp("rec") / "run.mcap"
    ns = "/rectest"
    msgs = list(team_stream(EPISODES, MAX_STEPS))
    from sdhn_msgs.msg import Hypergraph, PolicyWeights

    types = {o.topic: type(o.message) for o in msgs}
    # viz:=false (the default, named here because it matters): rosbags 0.11.9 cannot open a file
    # that also holds the protobuf viz channels.
    # (it reads every schema as ROS text); recordings with viz are tested in test_recording_viz
    command = [*ROS2, "run", "sdhn_sim", "recorder", "--ros-args", "-p", f"output:={out}",
               "-p", f"team_ns:={ns}", "-p", "viz:=false"]
    with own_node("rec_test_publisher") as node:
        pubs = {topic: node.create_publisher(cls, topics.absolute(ns, topic), STEP)
                for topic, cls in types.items()}
        weights = node.create_publisher(PolicyWeights, topics.absolute(ns, topics.WEIGHTS),
                                        LATCHED)
        graphs = node.create_publisher(Hypergraph, topics.absolute(ns, topics.HYPERGRAPH),
                                       SENSOR)
        weights.publish(weights_message(1))  # before the recorder exists: must arrive latched
        with node_processes(command) as (recorder,):
            assert recorder.wait_for_line("ready", timeout=20), recorder.output
            deadline = time.monotonic() + 15
            every = [*pubs.values(), weights, graphs]
            while any(p.get_subscription_count() == 0 for p in every):
                assert time.monotonic() < deadline, f"recorder never subscribed:\n{recorder.output}"
                time.sleep(0.05)
            # v1 must have reached the recorder before v2 replaces it in the depth-1 writer's
            # history: a reliable KEEP_LAST 1 writer forgets an unacknowledged sample.
            assert weights.wait_for_all_acked(rclpy.duration.Duration(seconds=5))
            t0 = time.perf_counter()
            for o in msgs:
                pubs[o.topic].publish(o.message)
            for k in range(5):
                graphs.publish(hypergraph_message(k))
                time.sleep(0.01)
            weights.publish(weights_message(2))
            publish_s = time.perf_counter() - t0
            for p in [*pubs.values(), weights]:
                p.wait_for_all_acked(rclpy.duration.Duration(seconds=5))
            time.sleep(0.3)
            assert recorder.stop(timeout=5.0) == 0, recorder.output
            print(f"published {len(msgs)} step messages in {publish_s:.3f} s; recorder said:\n"
                  + "\n".join(line for line in recorder.lines if "closed" in line))
    yield out, ns


def test_recording_holds_every_step_of_every_topic(recorded: tuple[Path, str]) -> None:
    path, ns = recorded
    rec = read_recording(path)
    assert rec.truncated is None
    got = Counter(rec.topics())
    want = expected_counts(ns)
    for topic, count in want.items():
        assert got[topic] == count, f"{topic}: recorded {got[topic]}, published {count}"
    assert got[f"{ns}/policy/weights"] == 2, "latched v1 (published before start) and v2"
    assert got[f"{ns}/hypergraph"] >= 1
    # every (episode, step) of every robot's obs, and actions for all non-terminal steps
    lengths = {r.episode: r.length for r in summaries_from_messages(rec).values()}
    assert len(lengths) == EPISODES
    for i in range(4):
        obs_keys = {(m.episode, m.step) for _, m in rec.decoded(f"robot_{i}/obs")}
        act_keys = {(m.episode, m.step) for _, m in rec.decoded(f"robot_{i}/action")}
        assert obs_keys == {(e, t) for e, n in lengths.items() for t in range(n + 1)}
        assert act_keys == {(e, t) for e, n in lengths.items() for t in range(n)}


def test_rosbags_opens_the_recording(recorded: tuple[Path, str]) -> None:
    path, ns = recorded
    with AnyReader([path]) as reader:
        counts: Counter[str] = Counter()
        for conn, _, raw in reader.messages():
            msg: Any = reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] += 1
            if conn.topic == f"{ns}/state":
                assert msg.env_name == ENV and len(msg.state) == 4 * 57
    assert counts == Counter(read_recording(path).topics())


def test_replay_summary_equals_the_live_one(recorded: tuple[Path, str]) -> None:
    path, _ = recorded
    rec = read_recording(path)
    live = summaries_from_messages(rec)
    recomputed = summaries_from_states(rec)
    assert set(live) == set(recomputed) == set(range(EPISODES))
    for k, a in live.items():
        b = recomputed[k]
        assert (a.length, a.completed, a.makespan, a.missed_actions, a.policy_version) == (
            b.length, b.completed, b.makespan, b.missed_actions, b.policy_version), (a, b)
        assert b.episode_return == pytest.approx(a.episode_return, rel=1e-5, abs=1e-4)
    done = subprocess.run([*REPLAY, str(path), "--summary"], capture_output=True, text=True,
                          timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    rows = [line.split() for line in done.stdout.splitlines()[1:]]
    assert [int(r[0]) for r in rows] == list(range(EPISODES))
    assert [int(r[1]) for r in rows] == [live[k].length for k in range(EPISODES)]


def test_export_episode_writes_frames_on_the_matched_map(recorded: tuple[Path, str],
                                                         tmp_path: Path) -> None:
    path, _ = recorded
    done = subprocess.run([*REPLAY, str(path), "--export-episode", "1", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    frames = sorted(tmp_path.glob("frame_*.png"))
    length = summaries_from_messages(read_recording(path))[1].length
    assert len(frames) == length + 1
    assert "instance" in done.stdout, done.stdout
    from PIL import Image

    image = np.asarray(Image.open(frames[0]))
    assert image.shape == (12 * 16, 12 * 16, 3)
    missing = subprocess.run([*REPLAY, str(path), "--export-episode", "99", "--out",
                              str(tmp_path)], capture_output=True, text=True, timeout=60,
                             check=False)
    assert missing.returncode == 1 and "episode 99" in missing.stderr


def test_truncated_recording_reports_one_line_and_keeps_the_readable_part(
        tmp_path: Path) -> None:
    path = tmp_path / "crashed.mcap"
    msgs = list(team_stream(EPISODES, MAX_STEPS))
    with McapRosWriter(path, chunk_bytes=8 * 1024) as writer:
        for k, o in enumerate(msgs):
            writer.write(f"/sdhn/{o.topic}", o.message, log_time_ns=1_000_000 * (k + 1))
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 3])  # a writer killed mid-file
    rec = read_recording(cut)
    assert rec.truncated is not None
    assert 0 < rec.truncated.messages == len(rec.messages) < len(msgs)
    assert [m.data for m in rec.messages] == [m.data for m in read_recording(path).messages][
        : len(rec.messages)]
    done = subprocess.run([*REPLAY, str(cut), "--summary"], capture_output=True, text=True,
                          timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("replay: recording truncated after"), lines
    assert "last complete chunk at byte" in lines[0]
    not_mcap = tmp_path / "junk.mcap"
    not_mcap.write_bytes(b"hello")
    bad = subprocess.run([*REPLAY, str(not_mcap)], capture_output=True, text=True, timeout=60,
                         check=False)
    assert bad.returncode == 2 and "not an MCAP file" in bad.stderr
    assert "Traceback" not in bad.stderr


def test_recorder_never_overwrites_an_existing_file(tmp_path: Path) -> None:
    from sdhn_sim.recording.recorder_node import fresh_path

    first = tmp_path / "a.mcap"
    assert fresh_path(first) == first
    shutil.copy(__file__, first)
    assert fresh_path(first) == tmp_path / "a-1.mcap"
    assert sys.executable


def test_rate_republishes_every_message_on_its_topic(recorded: tuple[Path, str],
                                                     tmp_path: Path) -> None:
    """Replay at 2x into a second recorder: the same messages (bytes) arrive on the same topics."""
    path, ns = recorded
    again = tmp_path / "again.mcap"
    command = [*ROS2, "run", "sdhn_sim", "recorder", "--ros-args", "-p", f"output:={again}",
               "-p", f"team_ns:={ns}"]
    with node_processes(command) as (recorder,):
        assert recorder.wait_for_line("ready", timeout=20), recorder.output
        done = subprocess.run([*REPLAY, str(path), "--rate", "2", "--wait", "10"],
                              capture_output=True, text=True, timeout=60, check=False)
        assert done.returncode == 0, done.stderr
        assert "republished" in done.stdout
        time.sleep(0.5)
        assert recorder.stop(timeout=5.0) == 0, recorder.output
    original = read_recording(path)
    replayed = read_recording(again)
    step_topics = {t for t in original.topics() if "/robot_" in t or t.endswith(("/state",
                                                                                 "/episode"))}
    for topic in step_topics:
        want = [m.data for m in original.messages if m.topic == topic]
        got = [m.data for m in replayed.messages if m.topic == topic]
        assert got == want, f"{topic}: {len(got)} of {len(want)} messages replayed"


def test_rate_delivers_every_message_to_a_slow_subscriber(tmp_path: Path) -> None:
    """400 states recorded 0.1 ms apart, replayed at --rate 10 to a reliable keep-all subscriber
    that takes 2 ms per message: every one arrives. (A keep-last subscriber this slow loses
    messages in its own queue, which DDS acknowledges on arrival: README, Reliability.)"""
    import threading

    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    from sdhn_msgs.msg import TeamState

    n, ns = 400, "/rate_slow"
    path = tmp_path / "burst.mcap"
    with McapRosWriter(path) as w:
        for k in range(n):
            m = TeamState()
            m.episode, m.step, m.num_robots = 0, k, 1
            w.write(topics.absolute(ns, topics.STATE), m, 1_000_000_000 + k * 100_000)
    got: list[int] = []

    def slow(msg: Any) -> None:
        time.sleep(0.002)
        got.append(int(msg.step))

    keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
    with own_node_and_executor("slow_sub") as (node, executor):
        node.create_subscription(TeamState, topics.absolute(ns, topics.STATE), slow, keep_all)
        spin = threading.Thread(target=executor.spin, daemon=True)
        spin.start()
        done = subprocess.run([*REPLAY, str(path), "--rate", "10", "--wait", "10"],
                              capture_output=True, text=True, timeout=120, check=False)
        deadline = time.monotonic() + 15
        while len(got) < n and time.monotonic() < deadline:
            time.sleep(0.1)
    assert done.returncode == 0, done.stderr
    assert got == list(range(n)), f"{len(got)} of {n} delivered"


@pytest.mark.parametrize("rate", ["1e-300", "1e300", "nan", "-1"])
def test_rate_out_of_range_is_one_line(recorded: tuple[Path, str], rate: str) -> None:
    path, _ = recorded
    done = subprocess.run([*REPLAY, str(path), "--rate", rate], capture_output=True, text=True,
                          timeout=60, check=False)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert "--rate" in done.stderr.strip().splitlines()[-1]


def test_rate_reports_messages_a_stalled_subscriber_never_acknowledged(tmp_path: Path) -> None:
    """A matched subscriber that stops (SIGSTOP: its process frozen, nothing acknowledged): replay
    says how many messages were not acknowledged, per topic, and exits 1 (it used to exit 0)."""
    import signal

    from sdhn_msgs.msg import TeamState

    ns = "/rate_stalled"
    path = tmp_path / "burst.mcap"
    with McapRosWriter(path) as w:
        for k in range(300):
            m = TeamState()
            m.step = k
            w.write(topics.absolute(ns, topics.STATE), m, 1_000_000_000 + k * 1_000_000)
    command = [*ROS2, "run", "sdhn_sim", "recorder", "--ros-args", "-p",
               f"output:={tmp_path / 'rec.mcap'}", "-p", f"team_ns:={ns}"]
    with node_processes(command) as (recorder,):
        assert recorder.wait_for_line("ready", timeout=20), recorder.output
        # 300 messages 1 ms apart at --rate 0.03: 10 s of replay. The recorder freezes once its
        # status line (every 5 s) counts received messages: matched and acknowledging, whatever
        # the load (a fixed delay from the replay's start lost that race on a loaded host).
        replay = subprocess.Popen([*REPLAY, str(path), "--rate", "0.03", "--wait", "10"],
                                  stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 60
        while not any(re.search(r"status: [1-9]", line) for line in recorder.lines):
            assert time.monotonic() < deadline and replay.poll() is None, recorder.output
            time.sleep(0.05)
        recorder.proc.send_signal(signal.SIGSTOP)
        try:
            out, err = replay.communicate(timeout=120)
        finally:
            recorder.proc.send_signal(signal.SIGCONT)
    done = subprocess.CompletedProcess(replay.args, replay.returncode, out, err)
    assert done.returncode == 1, (done.returncode, done.stderr)
    line = done.stderr.strip().splitlines()[-1]
    assert "not acknowledged" in line and f"{ns}/state=" in line, done.stderr
