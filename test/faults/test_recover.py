"""``replay FILE --recover OUT.mcap`` (issue 54, item 8): a recording whose recorder was killed
(no summary, footer or end magic: what SIGKILL leaves, written here by the project's own writer
stopped before close) is refused by the independent readers ``rosbags`` and ``mcap``'s indexed
reader; its recovered copy is read by both, with every message of the complete chunks, the
topics' QoS and type names, and the rosbag2 metadata record."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from rclpy.serialization import serialize_message

from sdhn_base.ros.qos import STEP
from sdhn_base.yaml_io import load_yaml
from sdhn_msgs.msg import EpisodeSummary, TeamState
from sdhn_sim.recording import rosbag2
from sdhn_sim.recording.writer import McapRosWriter

REPLAY = [sys.executable, "-m", "sdhn_bringup.ros2_cli", "run", "sdhn_sim", "replay"]
STATES = 400


def killed_recording(tmp_path: Path) -> Path:
    """The bytes a recorder killed mid-run leaves: complete chunks, no summary (small chunks so
    several are complete; the writer writes every record through at once)."""
    live = tmp_path / "live.mcap"
    writer = McapRosWriter(live, chunk_bytes=4096)
    writer.add_topic("/sdhn/state", [STEP], "RIHS01_" + "0" * 64)
    for step in range(STATES):
        msg = TeamState(env_name="maif-tiny", episode=0, step=step, num_robots=4)
        writer.write_serialized("/sdhn/state", "sdhn_msgs/msg/TeamState", serialize_message(msg),
                                1_000_000_000 + step * 1_000_000)
        if step % 100 == 99:
            writer.write_serialized("/sdhn/episode", "sdhn_msgs/msg/EpisodeSummary",
                                    serialize_message(EpisodeSummary(episode=step // 100)),
                                    1_000_000_000 + step * 1_000_000)
    killed = tmp_path / "killed.mcap"
    shutil.copyfile(live, killed)  # before close(): as SIGKILL would leave it
    writer.close()
    return killed


def read_with_rosbags(path: Path) -> tuple[dict[str, int], dict[str, str]]:
    from rosbags.rosbag2 import Reader

    with Reader(path) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        types = {c.topic: c.msgtype for c in reader.connections}
        assert sum(1 for _ in reader.messages()) == sum(counts.values())
    return counts, types


def read_with_mcap(path: Path) -> tuple[int, dict[str, str]]:
    from mcap.reader import make_reader

    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, "no summary"
        n = sum(1 for _ in reader.iter_messages())
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    return n, meta.get(rosbag2.METADATA_RECORD, {})


def test_a_killed_recording_is_refused_by_independent_readers_and_its_recovery_is_not(
        tmp_path: Path) -> None:
    killed = killed_recording(tmp_path)
    with pytest.raises(Exception):  # noqa: B017 - each reader has its own error type
        read_with_rosbags(killed)
    with pytest.raises(Exception):  # noqa: B017
        read_with_mcap(killed)

    out = tmp_path / "recovered.mcap"
    done = subprocess.run([*REPLAY, str(killed), "--recover", str(out)], capture_output=True,
                          text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "recording truncated" in done.stderr and f"wrote {out}" in done.stdout, done

    counts, types = read_with_rosbags(out)
    readable = int(done.stdout.split(": ")[1].split()[0])  # "wrote OUT: N messages of ..."
    assert 0 < readable < STATES + STATES // 100, done.stdout  # the complete chunks only
    assert sum(counts.values()) == readable, counts
    assert types["/sdhn/state"] == "sdhn_msgs/msg/TeamState", types
    n, meta = read_with_mcap(out)
    assert n == readable
    bag = load_yaml(meta["serialized_metadata"], what="metadata")
    assert bag["message_count"] == readable, bag
    state = next(t for t in bag["topics_with_message_count"]
                 if t["topic_metadata"]["name"] == "/sdhn/state")
    assert "reliable" in str(state["topic_metadata"]["offered_qos_profiles"]), state

    again = subprocess.run([*REPLAY, str(killed), "--recover", str(out)], capture_output=True,
                           text=True, timeout=120, check=False)
    assert again.returncode == 0 and "recovered-1.mcap" in again.stdout, again.stdout
    assert read_with_mcap(out)[0] == readable  # the first copy is never replaced


def test_recover_into_a_missing_directory_is_one_line(tmp_path: Path) -> None:
    killed = killed_recording(tmp_path)
    done = subprocess.run([*REPLAY, str(killed), "--recover", str(tmp_path / "no" / "x.mcap")],
                          capture_output=True, text=True, timeout=120, check=False)
    errors = [ln for ln in done.stderr.splitlines() if "error" in ln]
    assert done.returncode == 2 and len(errors) == 1 and "--recover" in errors[0], done.stderr
