"""Disk: weights files and checkpoints are written to a temp file and renamed. A process
SIGKILLed at random moments while it rewrites them in a loop always leaves a valid pair."""

from __future__ import annotations

import random
import signal
import sys
import time
from pathlib import Path

from ros.processes import NodeProcess

from sdhn_policy.weights import load_actor_file
from sdhn_train.checkpoint import load_checkpoint

KILLS = 12


def test_kill_during_writes_leaves_previous_files_valid(tmp_path: Path) -> None:
    rng = random.Random(7)
    versions, leftovers = [], 0
    t_start = time.monotonic()
    for _k in range(KILLS):
        proc = NodeProcess([sys.executable, str(Path(__file__).with_name("disk_writer.py")),
                            str(tmp_path)])
        assert proc.wait_for_line("writing", timeout=30), proc.output
        time.sleep(rng.uniform(0.05, 0.6))  # a random moment inside the write loop
        proc.proc.send_signal(signal.SIGKILL)
        proc.proc.wait()
        assert proc.proc.returncode == -signal.SIGKILL, proc.output
        blob = load_actor_file(tmp_path / "actor.safetensors")  # raises if torn or corrupt
        arrays, meta = load_checkpoint(tmp_path / "checkpoint")
        assert arrays["w"].shape == (512, 1024)
        versions.append((blob.version, int(meta["version"])))
        leftovers = len(list(tmp_path.glob(".*.tmp")))
    took = time.monotonic() - t_start
    print(f"{KILLS} kills in {took:.1f}s; (weights, checkpoint) version after each: {versions}; "
          f"temp files left over: {leftovers}")
    assert len({v for v, _ in versions}) > 1, f"the writer never got past a first write: {versions}"
