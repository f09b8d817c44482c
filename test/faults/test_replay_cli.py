"""``replay`` as a user drives it at the edges: SIGTERM while serving, an ``--out`` in a
directory that does not exist, a ``--host`` that is not this machine's, an IPv6 address."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "maif-tiny-pre-instance-id.mcap"
REPLAY = [sys.executable, "-m", "sdhn_sim.ros2_cli", "run", "sdhn_sim", "replay"]


def replay(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*REPLAY, *args], capture_output=True, text=True, timeout=60,
                          check=False)


def serve_then(signum: int, *args: str) -> tuple[int, str, str]:
    """Start ``replay --foxglove``, wait for its serving line, send ``signum``."""
    proc = subprocess.Popen([*REPLAY, str(FIXTURE), "--foxglove", "--port", "0", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    lines = []
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        lines.append(line)
        if "serving" in line or not line:
            break
    proc.send_signal(signum)
    out, err = proc.communicate(timeout=20)
    return proc.returncode, "".join(lines) + out, err


def test_sigterm_stops_foxglove_serving_with_its_line_and_exit_0() -> None:
    # It exited 143 (killed by SIGTERM), without the line saying what it had served.
    code, out, err = serve_then(signal.SIGTERM)
    assert "serving" in out, out + err
    assert code == 0, f"exit {code}\n{out}{err}"
    assert "replay: stopped after 0 viz messages" in out, out
    assert "Traceback" not in err, err


def test_add_viz_out_in_a_missing_directory_is_one_line_and_creates_nothing(
        tmp_path: Path) -> None:
    # It created every missing directory of the path (at the root of the file system too).
    missing = tmp_path / "no" / "such"
    r = replay(str(FIXTURE), "--add-viz", "--out", str(missing / "x.mcap"))
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "--out" in lines[0] and "not a directory" in lines[0], lines
    assert not (tmp_path / "no").exists()


@pytest.mark.parametrize("host", ["203.0.113.7", "no-such-host.invalid"])
def test_a_host_that_is_not_ours_is_named_as_host(host: str) -> None:
    # A bad --host was reported as a --port problem.
    r = replay(str(FIXTURE), "--foxglove", "--host", host, "--port", "0")
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("replay: error: --host:"), lines


@pytest.mark.parametrize(("host", "url"), [("::1", "ws://[::1]:8765"),
                                             ("127.0.0.1", "ws://127.0.0.1:8765"),
                                             ("localhost", "ws://localhost:8765")])
def test_urls_put_an_ipv6_address_in_brackets(host: str, url: str) -> None:
    # "ws://::1:8765" was printed for --host ::1 (the viz node and replay print ws_url's).
    from sdhn_sim.viz.server import ws_url

    assert ws_url(host, 8765) == url
