"""What killed processes leave behind is cleaned at the next start, only when its owner is gone:
the temporary files of atomic writes (a real writer process killed mid-write), and Fast DDS
shared-memory segments in /dev/shm (a real node process killed with SIGKILL)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sdhn_base import litter
from sdhn_policy.weights import atomic_write_bytes

REPO = Path(__file__).resolve().parents[2]

WRITER = """
import os, sys, tempfile
d = sys.argv[1]
fd, tmp = tempfile.mkstemp(prefix=f".ckpt.json.{os.getpid()}.", suffix=".tmp", dir=d)
os.write(fd, b"half")
print(tmp, flush=True)
sys.stdin.read()  # killed here, mid-write
"""


def test_tmp_of_a_killed_writer_is_removed_at_the_next_write(tmp_path: Path) -> None:
    p = subprocess.Popen([sys.executable, "-c", WRITER, str(tmp_path)], stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout is not None
    leftover = Path(p.stdout.readline().strip())
    live = subprocess.Popen([sys.executable, "-c", WRITER, str(tmp_path)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    assert live.stdout is not None
    live_tmp = Path(live.stdout.readline().strip())
    try:
        p.kill()
        p.wait()
        assert leftover.exists()
        atomic_write_bytes(tmp_path / "ckpt.json", b"{}")
        assert not leftover.exists(), "a dead writer's .tmp survived the next start"
        assert live_tmp.exists(), "a live writer's .tmp was removed"
    finally:
        live.kill()
        live.wait()
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")) == [
        live_tmp.name]


@pytest.mark.ros
def test_fastdds_segments_of_a_killed_node_are_removed_live_ones_kept(monkeypatch) -> None:
    monkeypatch.setattr(litter, "MIN_AGE_S", 1.0)  # not 0: never judge a starting process
    before = set(os.listdir("/dev/shm"))
    cmd = [sys.executable, "-m", "sdhn_bringup.ros2_cli", "run", "sdhn_policy", "actor",
           "--ros-args", "-r", "__ns:=/litter/robot_0", "-p", "team_ns:=/litter",
           "-p", "robot_id:=0", "-p", "num_robots:=1"]
    victim = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              env={**os.environ, "PYTHONUNBUFFERED": "1"})
    keeper = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        for proc in (victim, keeper):
            assert proc.stdout is not None
            deadline = time.monotonic() + 60
            while "ready" not in proc.stdout.readline():
                assert time.monotonic() < deadline and proc.poll() is None, "node never ready"
        new = {n for n in set(os.listdir("/dev/shm")) - before
               if re.fullmatch(r"fastrtps_[0-9a-f]{16}_el", n)}
        assert len(new) == 2, f"expected one segment per node, got {new}"
        victim.send_signal(signal.SIGKILL)
        victim.wait()
        time.sleep(1.1)
        assert litter.clean_fastdds_shm() >= 1
        left = {n for n in new if os.path.exists(f"/dev/shm/{n}")}
        assert len(left) == 1, f"expected only the live node's segment left, got {left}"
        assert os.path.exists(f"/dev/shm/{next(iter(left))[:-3]}")
        assert keeper.poll() is None
    finally:
        for proc in (victim, keeper):
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                proc.wait(timeout=20)
