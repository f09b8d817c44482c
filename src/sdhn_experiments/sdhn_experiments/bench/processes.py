"""What the deployment benchmarks share: starting and stopping their processes, reading a
process's CPU time, and random actor weights (the cost of a step does not depend on how good the
policy is, so no training is needed). Used by ``ros``, ``fleet`` and ``decision_latency``."""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from sdhn_experiments.bench import CHECKOUT
from sdhn_sim.envs.maif_instances import MAIF_CONFIGS

ROS2 = [sys.executable, "-m", "sdhn_bringup.ros2_cli", "run"]
ENVS = {c.num_robots: name for name, c in MAIF_CONFIGS.items() if name != "maif-solo"}
"""N -> the MAIF task with N robots: 4 (maif-tiny), 10, 16, 20, 30, 40, 60, 100."""
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """CPU time (user + system, every thread) a live process has used, from /proc/<pid>/stat;
    0.0 once it is gone (the caller reads before it stops the process)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return 0.0
    fields = stat[stat.rindex(")") + 2:].split()  # the command name may hold spaces
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime (fields 14, 15)


def make_weights(out: Path) -> Path:
    """A MAIF actor (57 observations, 5 actions) with random weights: out/actor.safetensors."""
    from sdhn_policy.weights import ActorSpec, encode_actor, save_actor_file

    spec = ActorSpec(obs_size=57, num_actions=5)
    rng = np.random.default_rng(0)
    tensors = {k: (rng.standard_normal(s) * 0.2).astype(np.float32)
               for k, s in spec.tensor_shapes().items()}
    path = out / "actor.safetensors"
    save_actor_file(path, encode_actor(spec, tensors, version=1))
    return path


def wait_line(proc: subprocess.Popen[bytes], needle: str, timeout: float) -> tuple[bool, list[str]]:
    """Read the child's output until a line contains ``needle``; (found, lines read)."""
    seen: list[str] = []
    end = time.monotonic() + timeout
    assert proc.stdout is not None
    fd = proc.stdout.fileno()
    buf = b""
    while time.monotonic() < end:
        ready, _, _ = select.select([fd], [], [], 0.05)
        if not ready:
            continue
        chunk = os.read(fd, 65536)
        if not chunk:
            return False, seen
        buf += chunk
        *lines, rest = buf.split(b"\n")
        buf = rest
        text = [line.decode(errors="replace") for line in lines]
        seen += text
        if any(needle in line for line in text):
            return True, seen
    return False, seen


def spawn(args: list[str]) -> subprocess.Popen[bytes]:
    """A child run in the checkout, its output on a pipe that ``wait_line`` reads."""
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=CHECKOUT)


def stop(procs: list[subprocess.Popen[bytes]]) -> None:
    """SIGINT to every process first (they stop together), then wait up to 10 s for each and
    kill what is left."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(2)
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()

