"""Start real node processes for tests and stop them, always, with their output kept for asserts."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
ROS2 = [sys.executable, "-m", "sdhn_bringup.ros2_cli"]
NOTE_LINES = 8  # each process's output lines added to a failure inside node_processes


class NodeProcess:
    """A child process whose combined output is collected line by line in the background."""

    def __init__(self, args: Sequence[str]) -> None:
        self.args = list(args)
        self.proc = subprocess.Popen(
            self.args,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=REPO,
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    @property
    def output(self) -> str:
        return "\n".join(self.lines)

    def wait_for_line(self, needle: str, timeout: float) -> bool:
        """True once a line containing ``needle`` was printed; False on timeout or exit."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(needle in line for line in self.lines):
                return True
            if self.proc.poll() is not None:
                self._reader.join(timeout=1.0)
                return any(needle in line for line in self.lines)
            time.sleep(0.02)
        return False

    def where(self) -> str:
        """Where a process that does not stop is stuck, for the assertion message: its threads'
        native backtraces (gdb, when installed) or their kernel wait channels, and its last
        output lines (e.g. whether the node runner got as far as logging 'stopped')."""
        pid = self.proc.pid
        if shutil.which("gdb"):
            done = subprocess.run(["gdb", "-p", str(pid), "-batch", "-nx",
                                   "-ex", "thread apply all bt 25"],
                                  capture_output=True, text=True, timeout=60, check=False)
            stacks = "\n".join(line for line in done.stdout.splitlines()
                                if line.startswith(("#", "Thread ")))
        else:
            tasks = sorted(Path(f"/proc/{pid}/task").glob("*"))
            stacks = "\n".join(f"thread {t.name}: {(t / 'wchan').read_text()}" for t in tasks
                                if (t / "wchan").exists())
        last = "\n".join(self.lines[-5:])
        return f"pid {pid} ({' '.join(self.args[-8:])}) last output:\n{last}\n{stacks}"

    def stop(self, sig: int = signal.SIGINT, timeout: float = 5.0) -> int | None:
        """Send ``sig`` and wait; returns the exit code, or None if it had to be killed."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                return None
        self._reader.join(timeout=1.0)
        return self.proc.returncode


@contextmanager
def node_processes(*commands: Sequence[str]) -> Iterator[list[NodeProcess]]:
    """Start each command; on exit kill whatever still runs so no test leaks a process."""
    started = [NodeProcess(command) for command in commands]
    try:
        yield started
    except BaseException as failure:
        # Every process's last lines with the failure: an assert that names one process's
        # output (the simulator's) leaves out the actor that did not start or stop.
        for node in started:
            tail = "\n  ".join(node.lines[-NOTE_LINES:]) or "(no output)"
            failure.add_note(f"[{' '.join(node.args[-8:])[:160]}] last output:\n  {tail}")
        raise
    finally:
        for node in started:
            if node.proc.poll() is None:
                node.proc.kill()
                node.proc.wait()
