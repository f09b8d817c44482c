"""A node whose teardown hangs (as a Fast DDS participant-removal deadlock does) still ends: the
runner's watchdog prints where every thread is stuck and exits 1, so whoever stopped it is not
hung too."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

from sdhn_base.ros.runner import TEARDOWN_S

HANGING_NODE = textwrap.dedent("""
    import sys, time
    from rclpy.node import Node
    from sdhn_base.ros.runner import run_node

    class Stuck(Node):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            print("up", flush=True)  # built after the runner installed its signal handlers

        def destroy_node(self):
            print("destroying", flush=True)
            time.sleep(3600)  # holds the main thread like a deadlocked C++ destructor

    sys.exit(run_node(lambda ctx, _a: Stuck("stuck", context=ctx), ["stuck"]))
""")


def test_hanging_teardown_ends_the_process_with_its_stacks() -> None:
    proc = subprocess.Popen([sys.executable, "-c", HANGING_NODE], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    # SIGINT only once the runner's handlers are in place: sent during the imports (0.5 s after
    # the start was too early at load 20+) it ended the process before run_node ran.
    assert proc.stdout is not None
    first = proc.stdout.readline()
    assert first.strip() == "up", (first, proc.stderr.read() if proc.poll() is not None else "")
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        proc.send_signal(signal.SIGINT)  # until the runner's handler is installed and takes it
        try:
            out, err = proc.communicate(timeout=TEARDOWN_S + 10)
            break
        except subprocess.TimeoutExpired:
            continue
    else:
        proc.kill()
        raise AssertionError(f"the node did not end: {proc.communicate()}")
    assert "destroying" in first + out, (out, err)
    assert proc.returncode == 1, (proc.returncode, err)
    assert "Timeout" in err and "destroy_node" in err, err  # the stack says where it hung
