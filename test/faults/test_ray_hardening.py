"""The Ray backend started locally by run_experiments: every socket its processes listen on is
bound to loopback (Ray has no authentication), and SIGTERM ends it like the local backend (one
line, exit 130, no C++ stack dump, no process left)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from contextlib import suppress
from pathlib import Path

import pytest

pytest.importorskip("ray")

SUITE = """name: rayh
methods:
  mappo: {algo: mappo}
tasks:
  maif-solo: {env.max_steps: 20}
seeds: [1]
budgets:
  long:
    set:
      train.total_steps: 10000000
      env.num_envs: 2
      ppo.rollout_len: 32
      ppo.num_minibatches: 1
      eval.interval: 0
      log.checkpoint_interval: 64
      log.tensorboard: false
"""
LOOPBACK = {"0100007F", "00000000000000000000000001000000",  # 127.0.0.1, ::1 in /proc/net
            "0000000000000000FFFF00000100007F"}  # ::ffff:127.0.0.1


def _tree(root: int) -> set[int]:
    """``root`` and every process descended from it (from /proc)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with suppress(OSError, IndexError):
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            children.setdefault(ppid, []).append(int(stat.parent.name))
    out, todo = set(), [root]
    while todo:
        pid = todo.pop()
        if pid not in out:
            out.add(pid)
            todo += children.get(pid, [])
    return out


def _listening(pids: set[int]) -> list[tuple[int, str]]:
    """(pid, hex local address) of every TCP socket in LISTEN state that ``pids`` hold."""
    inodes: dict[str, int] = {}
    for pid in pids:
        with suppress(OSError):
            for fd in Path(f"/proc/{pid}/fd").iterdir():
                with suppress(OSError):
                    target = os.readlink(fd)
                    if target.startswith("socket:["):
                        inodes[target[8:-1]] = pid
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            cols = line.split()
            if cols[3] == "0A" and cols[9] in inodes:  # 0A: LISTEN
                found.append((inodes[cols[9]], cols[1].split(":")[0]))
    return found


def test_local_ray_listens_on_loopback_only_and_sigterm_is_one_line(tmp_path: Path) -> None:
    suite = tmp_path / "suite.yaml"
    suite.write_text(SUITE)
    logdir = tmp_path / "logs"
    ray_tmp = tempfile.mkdtemp(prefix="sdhnrh")  # short: Ray's socket paths must fit 107 bytes
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path), "RAY_TMPDIR": ray_tmp}
    env.pop("RAY_ADDRESS", None)
    proc = subprocess.Popen([sys.executable, "-m", "sdhn_experiments.experiments_cli",
                             str(suite), "--budget", "long", "--logdir", str(logdir),
                             "--backend", "ray", "--num-cpus", "1"], env=env,
                            start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    pids: set[int] = set()
    try:
        run = logdir / "maif-solo__mappo__s1"
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and not any((run / "checkpoints").glob("*.json")):
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.2)
        assert any((run / "checkpoints").glob("*.json")), "the Ray run never trained"
        pids = _tree(proc.pid)
        sockets = _listening(pids)
        assert sockets, "no listening socket found: the check would see nothing"
        exposed = [(pid, Path(f"/proc/{pid}/cmdline").read_bytes()[:80], addr)
                   for pid, addr in sockets if addr not in LOOPBACK]
        assert not exposed, exposed

        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 130, (proc.returncode, err[-3000:])
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert lines and "interrupted" in lines[-1], err[-3000:]
        assert "Traceback" not in err and "SIGTERM" not in err and "***" not in err, err[-3000:]
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and [p for p in pids if Path(f"/proc/{p}").exists()
                                               and _alive(p)]:
            time.sleep(0.2)
        assert not [p for p in pids if _alive(p)], "processes of the Ray run left behind"
    finally:
        with suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        for pid in pids:
            if _alive(pid):
                with suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        proc.wait()
        shutil.rmtree(ray_tmp, ignore_errors=True)


def _alive(pid: int) -> bool:
    """A live process (not a zombie awaiting its parent)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def test_a_run_larger_than_the_local_ray_is_refused_not_queued_forever(tmp_path: Path) -> None:
    """A run asking for more CPUs than --num-cpus would stay pending forever on Ray: refused
    (one line) before Ray starts."""
    from sdhn_experiments.experiments import ExperimentError, load_suite
    from sdhn_experiments.ray_backend import run_suite_ray

    suite = tmp_path / "suite.yaml"
    suite.write_text(SUITE.replace("      log.tensorboard: false\n",
                                   "      log.tensorboard: false\n      train.threads: 2\n"))
    runs = load_suite(suite, "long")
    with pytest.raises(ExperimentError, match="needs 2 CPUs"):
        run_suite_ray(runs, tmp_path / "logs", num_cpus=1)
    assert not any((tmp_path / "logs").glob("maif-solo*"))
