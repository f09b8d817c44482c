"""``replay FILE --export-episode K --gif/--mp4``: a real MCAP (messages of the real MAIF env,
written by the recorder's writer) becomes a GIF / MP4 that reads back with one frame per recorded
step, the robots where the recording has them, and one-line errors for what cannot be drawn."""

from __future__ import annotations

import subprocess
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from sdhn_msgs.msg import EpisodeSummary
from sdhn_sim.envs.render import robot_colors
from sdhn_sim.recording.animation import BAR_PX, CAPTION_PX
from sdhn_sim.recording.reader import episode_states, read_recording
from sdhn_sim.recording.writer import McapRosWriter

from .processes import ROS2
from .team_stream import hypergraph_message, team_stream

REPLAY = [*ROS2, "run", "sdhn_sim", "replay"]
EPISODES, MAX_STEPS, CELL = 3, 12, 10


def write(path: Path, hypergraphs: bool, completed: int | None = None) -> Path:
    """A maif-tiny recording of EPISODES episodes; ``completed``: that episode's summary says
    completed (the random actions of the stream never complete one)."""
    t = 1_000_000_000
    with McapRosWriter(path) as w:
        for k, o in enumerate(team_stream(EPISODES, MAX_STEPS, seed=3)):
            t += 1_000_000
            msg = o.message
            if isinstance(msg, EpisodeSummary) and msg.episode == completed:
                msg.completed, msg.makespan = True, msg.length
            w.write(f"/sdhn/{o.topic}", msg, t)
            if hypergraphs and o.topic == "state" and k % 7 == 0:
                w.write("/sdhn/hypergraph", hypergraph_message(k), t)
    return path


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write(tmp_path_factory.mktemp("anim") / "rec.mcap", hypergraphs=True)


def replay(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*REPLAY, *map(str, args)], capture_output=True, text=True,
                          timeout=120, check=False)


def colour_at(frame: np.ndarray, cell: tuple[int, int]) -> np.ndarray:
    x, y = cell
    return frame[CAPTION_PX + BAR_PX + y * CELL + CELL // 2, x * CELL + CELL // 2].astype(int)


def test_gif_has_a_frame_per_step_and_the_robots_where_they_were(recording: Path,
                                                                  tmp_path: Path) -> None:
    gif = tmp_path / "ep1.gif"
    done = replay(recording, "--export-episode", "1", "--gif", gif)
    assert done.returncode == 0, done.stderr
    st = episode_states(read_recording(recording), 1)
    frames = iio.imread(gif, index=None)
    assert frames.shape[0] == len(st.steps), (frames.shape, st.steps)
    assert frames.shape[1:3] == (12 * CELL + CAPTION_PX + BAR_PX, 12 * CELL), frames.shape
    assert f"{len(st.steps)} frames" in done.stdout, done.stdout
    # the robot that moved most: its colour sits on its recorded cell in every frame
    moved = np.abs(np.diff(st.positions, axis=0)).sum(axis=(0, 2))
    r = int(np.argmax(moved))
    assert moved[r] > 0, "the stream's random actions moved nobody"
    want = robot_colors(st.positions.shape[1])[r].astype(int)
    for k, frame in enumerate(frames):
        cell = (int(st.positions[k, r, 0]), int(st.positions[k, r, 1]))
        got = colour_at(frame[..., :3], cell)
        assert np.abs(got - want).max() <= 24, (k, cell, got, want)
    first, last = tuple(st.positions[0, r]), tuple(st.positions[-1, r])
    assert first != last or moved[r] > 1


def test_every_k_steps_keeps_the_last_and_mp4_reads_back(recording: Path,
                                                         tmp_path: Path) -> None:
    gif, mp4 = tmp_path / "ep0.gif", tmp_path / "ep0.mp4"
    done = replay(recording, "--export-episode", "0", "--gif", gif, "--mp4", mp4, "--every", "4")
    assert done.returncode == 0, done.stderr
    n = len(episode_states(read_recording(recording), 0).steps)
    want = len(range(0, n, 4)) + (0 if (n - 1) % 4 == 0 else 1)
    assert iio.imread(gif, index=None).shape[0] == want
    video = iio.imread(mp4, index=None, plugin="FFMPEG")
    assert video.shape[0] == want, video.shape
    assert not list(tmp_path.glob(".*.tmp")), "a temporary file was left"


def test_hypergraph_is_drawn_when_recorded(recording: Path, tmp_path: Path) -> None:
    plain, graph = tmp_path / "plain.gif", tmp_path / "graph.gif"
    assert replay(recording, "--export-episode", "0", "--gif", plain).returncode == 0
    done = replay(recording, "--export-episode", "0", "--gif", graph, "--hypergraph")
    assert done.returncode == 0, done.stderr
    assert "hypergraph on " in done.stdout and "hypergraph on 0" not in done.stdout, done.stdout
    a, b = iio.imread(plain, index=None), iio.imread(graph, index=None)
    assert a.shape == b.shape and not np.array_equal(a[-1], b[-1]), "no hyperedge was drawn"


def test_what_cannot_be_drawn_is_one_line(recording: Path, tmp_path: Path) -> None:
    gif = tmp_path / "x.gif"
    missing = replay(recording, "--export-episode", "99", "--gif", gif)
    assert missing.returncode == 1 and len(missing.stderr.strip().splitlines()) == 1, missing
    assert "episode 99" in missing.stderr and not gif.exists()
    bare = write(tmp_path / "bare.mcap", hypergraphs=False)
    none = replay(bare, "--export-episode", "0", "--gif", gif, "--hypergraph")
    assert none.returncode == 1 and none.stderr.strip().startswith("replay: error: --hypergraph")
    assert len(none.stderr.strip().splitlines()) == 1, none.stderr
    wrong = replay(recording, "--export-episode", "0", "--gif", tmp_path / "x.png")
    assert wrong.returncode == 2 and "--gif" in wrong.stderr.strip().splitlines()[-1]


def test_completed_picks_the_last_completed_episode_or_says_it_takes_the_last(
        recording: Path, tmp_path: Path) -> None:
    done = replay(recording, "--export-episode", "completed", "--gif", tmp_path / "a.gif")
    assert done.returncode == 0, done.stderr
    assert f"no recorded episode completed; exporting the last finished one (episode " \
           f"{EPISODES - 1})" in done.stdout, done.stdout
    one = write(tmp_path / "one.mcap", hypergraphs=False, completed=1)
    done = replay(one, "--export-episode", "completed", "--gif", tmp_path / "b.gif")
    assert done.returncode == 0, done.stderr
    assert "episode 1," in done.stdout and "completed, makespan" in done.stdout, done.stdout
