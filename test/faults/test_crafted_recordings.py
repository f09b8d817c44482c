"""Crafted MCAP files against ``sdhn_sim replay`` started like a user does (``scripts/ros2``, which
runs Python with ``-m``, so the working directory is on sys.path): a schema naming a module that
sits next to the file never imports it; garbage CDR is one line, never a traceback."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from mcap.writer import Writer

from sdhn_sim.recording.schema import ros2msg_schema

REPO = Path(__file__).resolve().parents[2]
ROS2 = str(REPO / "scripts" / "ros2")


def craft(path: Path, type_name: str, data: bytes, topic: str, *, count: int = 3,
          schema_text: str = "int32 x\n") -> Path:
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="crafted")
        schema = w.register_schema(name=type_name, encoding="ros2msg", data=schema_text.encode())
        channel = w.register_channel(topic=topic, message_encoding="cdr", schema_id=schema)
        for k in range(count):
            w.add_message(channel_id=channel, log_time=1_000_000 * (k + 1),
                          publish_time=1_000_000 * (k + 1), data=data, sequence=k)
        w.finish()
    return path


def replay(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([ROS2, "run", "sdhn_sim", "replay", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120, check=False)


@pytest.mark.parametrize("action", [["--summary"], ["--rate", "10", "--wait", "0"],
                                    ["--add-viz"], []])
@pytest.mark.parametrize("type_name", ["evilmod/msg/Boom", "evilmod/Boom",
                                       "sdhn_msgs/msg/Nope", "os/msg/system"])
def test_a_schema_name_never_imports_a_module(tmp_path: Path, type_name: str,
                                              action: list[str]) -> None:
    marker = tmp_path / "PWNED"
    (tmp_path / "evilmod.py").write_text(f"open({str(marker)!r}, 'w').write('ran')\n")
    rec = craft(tmp_path / "evil.mcap", type_name, b"\x00\x01\x00\x00\x05\x00\x00\x00",
                "/sdhn/state")
    done = replay(tmp_path, str(rec), *action)
    assert not marker.exists(), "a module named by the recording was imported"
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode in (0, 1), done.stderr


@pytest.mark.parametrize("action", [["--summary"], ["--add-viz"], ["--export-episode", "0",
                                                                   "--out", "{tmp}/frames"]])
def test_garbage_cdr_is_one_line(tmp_path: Path, action: list[str]) -> None:
    name = "sdhn_msgs/msg/TeamState"
    rec = craft(tmp_path / "garbage.mcap", name, b"\xff" * 37, "/sdhn/state",
                schema_text=ros2msg_schema(name))
    done = replay(tmp_path, str(rec), *[a.format(tmp=tmp_path) for a in action])
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode in (0, 1, 2), done.stderr


FIXTURE = REPO / "test" / "fixtures" / "maif-tiny-pre-instance-id.mcap"


def test_export_never_writes_over_existing_files(tmp_path: Path) -> None:
    (tmp_path / "taken").write_text("x")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "frame_00000.png").write_text("mine")
    for out in ("taken", "full", "taken/sub"):
        done = replay(tmp_path, str(FIXTURE), "--export-episode", "0", "--out",
                      str(tmp_path / out))
        assert done.returncode == 2, (out, done.stderr)
        assert len(done.stderr.strip().splitlines()) == 1 and "--out" in done.stderr
    assert (tmp_path / "full" / "frame_00000.png").read_text() == "mine"


def _small_disk() -> None:  # in the child: files may not grow past 8 KiB (EFBIG, like ENOSPC)
    import resource
    import signal

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (8 * 1024, 8 * 1024))


def test_add_viz_on_a_full_disk_is_one_line_and_leaves_nothing(tmp_path: Path) -> None:
    out = tmp_path / "out.mcap"
    done = subprocess.run([ROS2, "run", "sdhn_sim", "replay", str(FIXTURE), "--add-viz",
                           "--out", str(out)], cwd=tmp_path, capture_output=True, text=True,
                          timeout=120, check=False, preexec_fn=_small_disk)
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "cannot write" in done.stderr, (
        done.stderr)
    assert sorted(p.name for p in tmp_path.iterdir()) == [], "partial output left behind"


def craft_states(path: Path, env_name: str, instance_id: int,
                 positions_per_step: list[list[int]]) -> Path:
    """A recording of TeamStates of episode 0 with the given flat positions, one per step."""
    import array

    from rclpy.serialization import serialize_message

    from sdhn_msgs.msg import TeamState

    name = "sdhn_msgs/msg/TeamState"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="crafted")
        schema = w.register_schema(name=name, encoding="ros2msg",
                                   data=ros2msg_schema(name).encode())
        channel = w.register_channel(topic="/sdhn/state", message_encoding="cdr", schema_id=schema)
        for step, flat in enumerate(positions_per_step):
            msg = TeamState(env_name=env_name, episode=0, step=step, num_robots=len(flat) // 2,
                            instance_id=instance_id)
            msg.positions = array.array("i", flat)
            t = 1_000_000 * (step + 1)
            w.add_message(channel_id=channel, log_time=t, publish_time=t,
                          data=serialize_message(msg), sequence=step)
        w.finish()
    return path


GOOD = [1, 1, 2, 2, 3, 3, 4, 4]
OFF_MAP = {  # issue 54 item 5: IndexError, a canvas of max+1 cells (2.5 GiB a frame), or drawn
    "beyond the map": [1, 1, 2, 2, 3, 3, 900, 4],
    "negative": [1, 1, 2, 2, -3, 3, 4, 4],
    "huge": [1, 1, 2, 2, 3, 3, 40_000, 40_000],
    "odd length": [1, 1, 2, 2, 3],
    "another team size": [1, 1, 2, 2],
}


@pytest.mark.parametrize("known_map", [True, False])
def test_export_leaves_out_states_off_the_map_and_bounds_the_canvas(
        tmp_path: Path, known_map: bool) -> None:
    from sdhn_sim.recording.reader import MAX_BLANK_GRID, episode_frames, read_recording

    steps = [GOOD, *OFF_MAP.values(), GOOD]
    rec_path = craft_states(tmp_path / "off.mcap", "maif-tiny", 0 if known_map else -1, steps)
    frames = episode_frames(read_recording(rec_path), 0, cell_px=3)
    assert frames.steps == [0, len(steps) - 1], frames.steps
    assert f"{len(OFF_MAP)} recorded states left out" in frames.map_note, frames.map_note
    assert all(im.shape[0] <= MAX_BLANK_GRID * 3 for im in frames.images)
    done = replay(tmp_path, str(rec_path), "--export-episode", "0", "--gif",
                  str(tmp_path / "e.gif"))
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert "left out" in done.stdout, done.stdout


def test_export_of_an_episode_wholly_off_the_map_is_one_line(tmp_path: Path) -> None:
    rec_path = craft_states(tmp_path / "off.mcap", "maif-tiny", 0, [OFF_MAP["huge"]] * 3)
    done = replay(tmp_path, str(rec_path), "--export-episode", "0", "--out",
                  str(tmp_path / "frames"))
    assert done.returncode == 1, done.stdout + done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "episode 0" in done.stderr


@pytest.mark.parametrize("flag", ["--gif", "--mp4"])
def test_an_animation_path_that_is_a_directory_is_named_by_its_flag(tmp_path: Path,
                                                                    flag: str) -> None:
    """Issue 54 item 8: --gif at a directory reported the error under --out."""
    (tmp_path / "x.gif").mkdir()
    (tmp_path / "x.mp4").mkdir()
    target = tmp_path / ("x.gif" if flag == "--gif" else "x.mp4")
    done = replay(tmp_path, str(FIXTURE), "--export-episode", "0", flag, str(target))
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"replay: error: {flag}:"), lines
