"""How a node process built on ``run_node`` ends (sdhn_base.ros.runner).

Once a node has stopped (on_stop ran, "stopped" logged), the process ends without deleting its
DDS participant: Fast DDS 2.14 can deadlock there with a departing peer's discovery callback,
which the teardown watchdog turned into exit code 1 for a node that had stopped cleanly. What a
normal exit does is still done: non-daemon threads joined (an idle ThreadPoolExecutor's worker
told to end), atexit handlers run (buffered Python logging flushed), stdout flushed, the ROS log
file complete, and the node's endpoints leave the graph at once. The exit codes stay: 0 stopped,
the node's ``exit_code``, 1 FAILED, 2 a configuration error.

Observable: the participant's shared-memory segment (``/dev/shm/fastrtps_<id>``, which Fast DDS
unlinks when it deletes the participant) is still there after the process has exited.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

PROBE = textwrap.dedent("""
    import logging, logging.handlers, os, sys, threading, time
    from concurrent.futures import ThreadPoolExecutor
    from pathlib import Path
    from rclpy.node import Node
    from sdhn_base.errors import ConfigError
    from sdhn_base.ros.runner import run_node

    out, mode = Path(sys.argv[1]), sys.argv[2]
    # Buffered until logging.shutdown() (an atexit handler) flushes it.
    buffered = logging.handlers.MemoryHandler(
        1000, flushLevel=logging.CRITICAL, target=logging.FileHandler(out / "python.log"))
    log = logging.getLogger("probe")
    log.addHandler(buffered)
    log.setLevel(logging.INFO)

    class Probe(Node):
        def __init__(self, context):
            super().__init__("exit_probe", context=context)
            if mode == "config":
                raise ConfigError("probe_mode: 'config' is refused; allowed: anything else")
            if mode == "failed":
                self.create_timer(0.3, lambda: setattr(self, "failed_reason", "probe failed"))
            if mode == "code3":
                self.exit_code = 3
            if mode == "shutdown":  # a stop from inside, as the docstring of run_node allows
                self.create_timer(0.3, context.try_shutdown)
            print("up", flush=True)

    def late_write():
        time.sleep(0.3)
        (out / "thread.done").write_text("done")

    pools = []

    def on_stop(node):
        # This participant's own segment: its lock file (..._el) is held open by its owner.
        held = [os.readlink(f) for f in Path("/proc/self/fd").iterdir() if f.is_symlink()]
        own = {h.removesuffix("_el") for h in held if h.startswith("/dev/shm/fastrtps_")
               and not h.startswith("/dev/shm/fastrtps_port") and h.endswith("_el")}
        (out / "segments").write_text("\\n".join(sorted(own)))
        print("on_stop: not flushed here")  # stdout is a pipe: block-buffered
        log.info("closed")
        threading.Thread(target=late_write).start()  # not a daemon: the exit waits for it
        # Never shut down: the interpreter's exit tells its idle worker to end; a plain join of
        # the non-daemon threads would wait for it forever.
        pools.append(ThreadPoolExecutor(1))  # referenced: its worker stays
        pools[0].submit(lambda: None).result()

    sys.exit(run_node(lambda context, _args: Probe(context), ["probe", "--ros-args", "-r",
                      f"__ns:={sys.argv[3]}"], on_stop))
""")


def start(tmp_path: Path, mode: str, ns: str) -> tuple[subprocess.Popen[str], Path]:
    out = tmp_path / mode
    (out / "ros_log").mkdir(parents=True)
    env = dict(os.environ, ROS_LOG_DIR=str(out / "ros_log"))
    env.pop("PYTHONUNBUFFERED", None)  # stdout block-buffered, as a pipe makes it
    env.pop("FASTDDS_BUILTIN_TRANSPORTS", None)  # the default transports: shared memory too
    proc = subprocess.Popen([sys.executable, "-c", PROBE, str(out), mode, ns], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return proc, out


def wait_up(proc: subprocess.Popen[str]) -> None:
    assert proc.stdout is not None
    first = proc.stdout.readline()
    if first.strip() != "up":
        proc.kill()
        raise AssertionError((first, proc.communicate()))


def stop(proc: subprocess.Popen[str]) -> tuple[str, str]:
    proc.send_signal(signal.SIGINT)  # handlers are in place: "up" is printed by the built node
    try:
        return proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise AssertionError(f"the node did not end: {proc.communicate()}") from None


def test_a_stopped_node_exits_0_complete_and_leaves_the_graph_keeping_its_participant(
        tmp_path: Path) -> None:
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    ns = f"/sdhn_exit_{os.getpid()}"
    watch_ctx = Context()
    rclpy.init(context=watch_ctx, signal_handler_options=SignalHandlerOptions.NO)
    proc, out = start(tmp_path, "stop", ns)
    segments: list[Path] = []
    try:
        watcher = Node("exit_watcher", context=watch_ctx)

        def listed_within(seconds: float, wanted: bool) -> bool:
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline:
                if (("exit_probe", ns) in watcher.get_node_names_and_namespaces()) == wanted:
                    return True
                time.sleep(0.05)
            return False

        wait_up(proc)
        assert listed_within(20, True), "the probe never appeared in the graph"
        stdout, stderr = stop(proc)
        assert proc.returncode == 0, (proc.returncode, stdout, stderr)
        assert "on_stop: not flushed here" in stdout, stdout
        assert (out / "python.log").read_text().strip() == "closed", "atexit handlers did not run"
        assert (out / "thread.done").read_text() == "done", "a non-daemon thread was cut off"
        logs = list((out / "ros_log").glob("*.log"))
        assert len(logs) == 1 and "stopped" in logs[0].read_text(), (
            logs and logs[0].read_text(), stderr)
        segments = [Path(p) for p in (out / "segments").read_text().split()]
        assert segments, "no Fast DDS segment mapped (shared-memory transport off?)"
        # The participant was not deleted: Fast DDS would have unlinked its segment.
        assert all(p.exists() for p in segments), [(p, p.exists()) for p in segments]
        # Its node was destroyed, not left to the participant's lease (20 s): gone at once.
        assert listed_within(10, False), "the stopped node is still in the graph"
        watcher.destroy_node()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        rclpy.try_shutdown(context=watch_ctx)
        for path in segments:  # what the exit left: the next node's start would clean it
            path.unlink(missing_ok=True)
            Path(f"{path}_el").unlink(missing_ok=True)


@pytest.mark.parametrize(("mode", "code", "line"), [
    ("code3", 3, None),
    ("shutdown", 0, None),
    ("failed", 1, "probe: error: probe failed"),
])
def test_exit_codes_of_a_built_node_are_kept(tmp_path: Path, mode: str, code: int,
                                             line: str | None) -> None:
    proc, out = start(tmp_path, mode, f"/sdhn_exit_{mode}_{os.getpid()}")
    try:
        wait_up(proc)
        if mode in ("failed", "shutdown"):
            stdout, stderr = proc.communicate(timeout=60)  # it stops itself
        else:
            stdout, stderr = stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == code, (proc.returncode, stdout, stderr)
    if line is not None:
        assert line in stderr.splitlines(), stderr
    assert (out / "python.log").read_text().strip() == "closed", "on_stop or atexit did not run"
    for path in (out / "segments").read_text().split():
        Path(path).unlink(missing_ok=True)
        Path(f"{path}_el").unlink(missing_ok=True)


def test_a_configuration_error_is_exit_2_with_one_line(tmp_path: Path) -> None:
    proc, out = start(tmp_path, "config", f"/sdhn_exit_config_{os.getpid()}")
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 2, (proc.returncode, stdout, stderr)
    assert stderr.strip().splitlines() == [
        "probe: error: probe_mode: 'config' is refused; allowed: anything else"], stderr
    assert not (out / "python.log").read_text(), "on_stop ran for a node that was never built"
