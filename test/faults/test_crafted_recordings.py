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
