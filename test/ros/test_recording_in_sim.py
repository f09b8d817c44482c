"""Recording inside the simulator (``recorder: {where: sim}``, the sim's ``recording`` parameter):
the same deployment (seed, weights, greedy) recorded once by the recorder node and once by the
simulator holds the same messages per topic in the same order, with the same schemas and channel
QoS; rosbags and ``replay`` read it as they read the recorder's; the launcher's option is
validated and drops the recorder process; a simulator killed while recording leaves a file
readable up to its last chunk."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from rosbags.highlevel import AnyReader

from sdhn_bringup.launch_graph import node_parameters
from sdhn_bringup.launch_load import LaunchConfigError, load_config, resolve
from sdhn_sim.recording.reader import Recording, read_recording
from sdhn_sim.recording.rosbag2 import QOS_KEY, parse_offered_qos

from .deploy_helpers import actor_cmd, sim_cmd
from .processes import ROS2, node_processes

LAUNCH = [sys.executable, "-m", "sdhn_bringup", "configs/launch/deploy-tiny.yaml"]
MODEL = Path(__file__).resolve().parents[2] / "models" / "maif-tiny-sdhn"
STEP_TOPICS = ("state", "episode", *(f"robot_{i}/{k}" for i in range(4) for k in ("obs", "action")))


def run_recorded(where: str, root: Path, ns: str) -> Path:
    run = root / where
    cmd = [*LAUNCH, "--set", f"weights={MODEL}", "--set", f"run_dir={run}", "--set",
           f"recorder.where={where}", "--set", "episodes=2", "--set", "max_steps=20",
           "--set", "seed=3", "--set", f"team_ns={ns}"]
    with node_processes(cmd) as (launcher,):
        launcher.proc.wait(timeout=180)
    assert launcher.proc.returncode == 0, launcher.output
    assert f"recording: {run / 'recording.mcap'}" in launcher.output, launcher.output
    return run / "recording.mcap"


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Path]]:
    root = tmp_path_factory.mktemp("insim")
    yield {where: run_recorded(where, root, f"/insim_{where}") for where in ("node", "sim")}


def content(rec: Recording, topic: str) -> list[tuple[Any, ...]]:
    """The topic's messages in recorded order, each as its fields without the header (the
    stamps are wall clock); a step re-sent in the start handshake appears once."""
    seen: list[tuple[Any, ...]] = []
    for _, m in rec.decoded(f"/{topic}"):
        fields = tuple(repr(getattr(m, f)) for f in m.get_fields_and_field_types()
                       if f != "header")
        if not seen or fields != seen[-1]:
            seen.append(fields)
    return seen


def test_same_messages_per_topic_in_the_same_order(recordings: dict[str, Path]) -> None:
    node, sim = read_recording(recordings["node"]), read_recording(recordings["sim"])
    assert node.truncated is None and sim.truncated is None
    rel = {r: {t.split("/", 2)[2]: n for t, n in rec.topics().items()}
           for r, rec in (("node", node), ("sim", sim))}
    assert set(rel["sim"]) == set(STEP_TOPICS) == set(rel["node"]), rel
    for topic in STEP_TOPICS:
        a, b = content(node, topic), content(sim, topic)
        assert len(a) >= 2 and a == b, f"{topic}: {len(a)} vs {len(b)} messages"
    assert len(content(sim, "episode")) == 2


def test_schemas_and_channel_qos_match_the_recorders(recordings: dict[str, Path]) -> None:
    node, sim = read_recording(recordings["node"]), read_recording(recordings["sim"])
    schemas = {r: {s.name: s.data for s in rec.schemas.values()}
               for r, rec in (("node", node), ("sim", sim))}
    assert schemas["node"] == schemas["sim"]
    for topic in STEP_TOPICS:
        offers = []
        for rec in (node, sim):
            (channel,) = [c for c in rec.channels.values() if c.topic.endswith(f"/{topic}")]
            assert channel.message_encoding == "cdr"
            offers.append([(q.reliability, q.durability, q.history, q.depth)
                           for q in parse_offered_qos(channel.metadata[QOS_KEY])])
        assert offers[0] == offers[1] and len(offers[1]) == 1, (topic, offers)


def test_rosbags_and_replay_read_it_as_the_recorders(recordings: dict[str, Path]) -> None:
    with AnyReader([recordings["sim"]]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
    assert counts == read_recording(recordings["sim"]).topics()
    out = {}
    for where, path in recordings.items():
        done = subprocess.run([*ROS2, "run", "sdhn_sim", "replay", str(path), "--summary"],
                              capture_output=True, text=True, timeout=60, check=False)
        assert done.returncode == 0, done.stderr
        out[where] = done.stdout
    assert out["sim"] == out["node"] and out["sim"].count("\n") == 3, out


def test_launcher_option_is_validated_and_drops_the_recorder_process(tmp_path: Path) -> None:
    w = [f"weights={MODEL}", "env=maif-tiny", f"run_dir={tmp_path / 'run'}"]
    cfg = resolve(load_config(None, [*w, "recorder.where=sim"]))
    nodes = node_parameters(cfg)
    assert "/sdhn/recorder" not in nodes
    sim = nodes["/sdhn/sim"]
    assert sim["recording"] == str((tmp_path / "run" / "recording.mcap").resolve())
    assert sim["extra_subscribers"] == 0
    node_cfg = resolve(load_config(None, w))
    assert node_parameters(node_cfg)["/sdhn/sim"]["recording"] == ""
    assert node_parameters(node_cfg)["/sdhn/sim"]["extra_subscribers"] == 1
    off = resolve(load_config(None, [*w, "recorder={enabled: false, where: sim}"]))
    assert node_parameters(off)["/sdhn/sim"]["recording"] == ""
    with pytest.raises(LaunchConfigError, match=r"recorder.where: got 'actor'; allowed: node, "
                                                r"sim"):
        resolve(load_config(None, [*w, "recorder.where=actor"]))
    with pytest.raises(LaunchConfigError, match=r"recorder.where: sim .* allowed in mode train: "
                                                r"node"):
        resolve(load_config(None, [*w, "recorder.where=sim", "mode=train"]))


def test_sim_refuses_a_recording_path_it_cannot_use(tmp_path: Path) -> None:
    cmd = [*ROS2, "run", "sdhn_sim", "sim", "--ros-args", "-r", "__ns:=/insim_bad", "-p",
           "env:=maif-tiny", "-p", "recording:=..", "-p", "start_timeout:=1.0"]
    with node_processes(cmd) as (sim,):
        sim.proc.wait(timeout=60)
    assert sim.proc.returncode == 2, sim.output
    assert "recording: '..'; allowed:" in sim.output, sim.output


def test_a_killed_simulator_leaves_a_recording_readable_to_its_last_chunk(tmp_path: Path) -> None:
    """SIGKILL: no summary, but every complete chunk reads (replay says where it stops)."""
    out, ns = tmp_path / "killed.mcap", "/insim_kill"
    weights = MODEL / "actor.safetensors"
    commands = [sim_cmd(ns=ns, episodes=0, recording=str(out)),
                *(actor_cmd(i, 4, ns=ns, weights_file=str(weights)) for i in range(4))]
    with node_processes(*commands) as (sim, *_actors):
        assert sim.wait_for_line("starting episode 0", timeout=60), sim.output
        end = time.monotonic() + 60
        while out.stat().st_size < 60_000:  # chunks of 256 KiB (~40 kB compressed) written
            assert time.monotonic() < end and sim.proc.poll() is None, sim.output
            time.sleep(0.1)
        sim.proc.send_signal(signal.SIGKILL)
        sim.proc.wait(timeout=10)
    rec = read_recording(out)
    assert rec.truncated is not None and rec.truncated.messages == len(rec.messages) > 100
    counts = {t.rsplit("/", 2)[-2] + "/" + t.rsplit("/", 1)[-1] if "robot_" in t
              else t.rsplit("/", 1)[-1]: n for t, n in rec.topics().items()}
    assert counts["robot_0/obs"] > 10 and counts["state"] > 10, counts
    done = subprocess.run([*ROS2, "run", "sdhn_sim", "replay", str(out), "--summary"],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.strip().startswith("replay: recording truncated after"), done.stderr
