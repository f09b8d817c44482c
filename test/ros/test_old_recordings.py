"""Recordings made before TeamState and EpisodeSummary carried ``instance_id`` (and before
RobotObservation carried ``obs_age``) still read, summarise, render, convert (--add-viz) and
republish; the missing id reads as -1 ("unknown") and nothing guesses the world in its place; the
missing age reads as 0 (no latency existed then). The fixture was made with the code of that time
(test/fixtures/README.md)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from sdhn_base.ros.topics import VIZ_EPISODES, VIZ_SCENE
from sdhn_sim.recording.reader import (
    current_cdr,
    decode,
    episode_frames,
    episode_rows,
    read_recording,
    write_with_viz,
)

from .processes import ROS2

OLD = Path(__file__).resolve().parents[1] / "fixtures" / "maif-tiny-pre-instance-id.mcap"


def test_old_team_messages_decode_with_unknown_instance() -> None:
    rec = read_recording(OLD)
    assert rec.truncated is None
    old = {m.type_name for m in rec.messages if m.old_schema}
    assert old == {"sdhn_msgs/msg/TeamState", "sdhn_msgs/msg/EpisodeSummary",
                   "sdhn_msgs/msg/RobotObservation"}, old
    observations = list(rec.decoded("/obs", "sdhn_msgs/msg/RobotObservation"))
    assert observations and {int(o.obs_age) for _, o in observations} == {0}
    assert all(len(o.obs) == 57 for _, o in observations)
    states = list(rec.decoded("/state"))
    assert len(states) == 26
    assert {int(s.instance_id) for _, s in states} == {-1}
    assert all(len(current_cdr(raw)) == len(raw.data) + 4 for raw, _ in states)
    first = states[0][1]
    assert first.env_name == "maif-tiny" and first.num_robots == 4 and len(first.positions) == 8
    for raw in rec.messages:  # messages whose type did not change decode as they are
        if raw.encoding == "cdr" and not raw.old_schema:
            assert current_cdr(raw) is raw.data
            decode(raw)


def test_old_recording_summarises_as_it_did() -> None:
    rows = episode_rows(read_recording(OLD))
    # As printed by the reader of the time: two 12-step episodes, not completed.
    assert [(r.episode, r.length, r.completed, r.makespan, r.collisions) for r, _ in rows] == [
        (0, 12, False, None, 11), (1, 12, False, None, 16)], rows
    assert [round(r.episode_return, 3) for r, _ in rows] == [-7.508, -10.309]
    assert all(source == "episode" for _, source in rows)


def test_old_recording_renders_on_a_blank_grid_and_says_why() -> None:
    frames = episode_frames(read_recording(OLD), 1)
    assert len(frames.images) == 13 and frames.steps == list(range(13))
    assert "predates TeamState.instance_id" in frames.map_note, frames.map_note


def test_old_recording_converts_to_one_with_viz(tmp_path: Path) -> None:
    out = tmp_path / "old-viz.mcap"
    done = write_with_viz(read_recording(OLD), out)
    assert done.team_ns == "/sdhn" and done.copied == 233
    assert done.written.get(VIZ_SCENE) == 26 and done.written.get(VIZ_EPISODES) == 2, done
    assert not done.dropped, done.dropped
    topics = read_recording(out).topics()
    assert topics[VIZ_SCENE] == 26 and topics[VIZ_EPISODES] == 2


@pytest.mark.parametrize("args", [["--summary"], ["--export-episode", "0"]])
def test_replay_cli_reads_the_old_recording(args: list[str], tmp_path: Path) -> None:
    extra = ["--out", str(tmp_path / "frames")] if "--export-episode" in args else []
    done = subprocess.run([*ROS2, "run", "sdhn_sim", "replay", str(OLD), *args, *extra],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    if "--summary" in args:
        assert "-7.508" in done.stdout and "-10.309" in done.stdout, done.stdout
    else:
        assert len(list((tmp_path / "frames").glob("frame_*.png"))) == 13
