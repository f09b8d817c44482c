"""``replay`` as a user drives it at the edges: SIGTERM while serving, an ``--out`` in a
directory that does not exist, a ``--host`` that is not this machine's, an IPv6 address."""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "maif-tiny-pre-instance-id.mcap"
REPLAY = [sys.executable, "-m", "sdhn_bringup.ros2_cli", "run", "sdhn_sim", "replay"]


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


def test_foxglove_loop_on_a_short_file_neither_spams_nor_interleaves_and_stops_past_a_hog(
        ) -> None:
    """Issue 54 item 8: ``--loop`` on a short file printed a line every 40 ms; the server's
    threads wrote into the middle of replay's lines; a client that never reads held SIGTERM."""
    import json
    import socket

    from websockets.sync.client import connect

    proc = subprocess.Popen([*REPLAY, str(FIXTURE), "--foxglove", "--port", "0", "--loop",
                             "--rate", "1000"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    first = proc.stdout.readline()
    port = int(first.split("ws://127.0.0.1:")[1].split()[0])
    hog = socket.create_connection(("127.0.0.1", port))  # connects, never upgrades nor reads
    try:
        with connect(f"ws://127.0.0.1:{port}", proxy=None,
                     subprotocols=["foxglove.sdk.v1"]) as ws:  # type: ignore[list-item]
            json.loads(ws.recv(timeout=10))
            scene = next(c["id"] for c in json.loads(ws.recv(timeout=10))["channels"]
                         if c["topic"] == "/viz/scene")
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 1, "channelId": scene}]}))
            frames = 0
            deadline = time.monotonic() + 3.0
            while time.monotonic() < deadline:
                with contextlib.suppress(TimeoutError):
                    frames += isinstance(ws.recv(timeout=0.5), bytes)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    finally:
        hog.close()
        if proc.poll() is None:
            proc.kill()
    lines = (first + out).splitlines()
    assert proc.returncode == 0, f"exit {proc.returncode}\n{out}{err}"
    assert frames > 0, out
    assert all(ln.startswith("replay: ") for ln in lines), lines  # whole lines, none spliced
    served = [ln for ln in lines if "replay: served" in ln]
    assert len(served) <= 1, f"{len(served)} progress lines in ~3 s of --loop"
    assert any(ln.startswith("replay: stopped after") for ln in lines), lines
