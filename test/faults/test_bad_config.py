"""Bad configuration: one line naming the parameter, exit code 2, and no topic of the team
namespace ever appears in the ROS graph (watched from the test process while the node runs)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from ros.processes import ROS2, NodeProcess

from sdhn_base.polling import wait_until

from .graph import Peer

pytestmark = pytest.mark.ros


def node_cmd(package: str, exe: str, ns: str, *params: str) -> list[str]:
    args = [*ROS2, "run", package, exe, "--ros-args", "-r", f"__ns:={ns}", "-p", f"team_ns:={ns}"]
    for p in params:
        args += ["-p", p]
    return args


def corrupt_checkpoint(run_dir: Path) -> Path:
    d = run_dir / "checkpoints"
    d.mkdir(parents=True)
    (d / "step_000000000384.safetensors").write_bytes(b"\x00" * 64)
    (d / "step_000000000384.json").write_text(json.dumps({"format": "sdhn-checkpoint/1",
                                                       "tensors_sha256": "0" * 64}))
    return run_dir


CASES = {
    "sim-unknown-env": (("sdhn_sim", "sim"), ["env:=maif-nope"], "env:"),
    "sim-zero-deadline": (("sdhn_sim", "sim"), ["env:=maif-tiny", "step_deadline:=0.0"],
                          "step_deadline:"),
    "actor-robot-id-too-big": (("sdhn_policy", "actor"), ["robot_id:=4", "num_robots:=4"],
                               "robot_id:"),
    # Typed descriptors: ROS itself refuses a wrong type or an out-of-range value.
    "actor-float-robot-id": (("sdhn_policy", "actor"), ["robot_id:=1.5", "num_robots:=4"],
                             "robot_id:"),
    "sim-negative-episodes": (("sdhn_sim", "sim"), ["env:=maif-tiny", "episodes:=-1"],
                              "episodes:"),
    "actor-negative-action-readers": (("sdhn_policy", "actor"),
                                      ["robot_id:=0", "num_robots:=4", "action_readers:=-1"],
                                      "action_readers:"),
    "actor-missing-weights": (("sdhn_policy", "actor"),
                              ["robot_id:=0", "num_robots:=4",
                               "weights_file:=/nonexistent/actor.safetensors"], "weights_file:"),
    "trainer-unknown-env": (("sdhn_train", "trainer"), ["env:=nope"], "env:"),
    "trainer-missing-config": (("sdhn_train", "trainer"),
                               ["env:=maif-tiny", "config:=/nonexistent/train.yaml"], "config:"),
    # Issue 16: a wrong parameter type, a bad namespace, unreadable YAML: one line, exit 2.
    "actor-string-robot-id": (("sdhn_policy", "actor"), ["robot_id:=abc", "num_robots:=4"],
                              "robot_id"),
    "actor-bad-team-ns": (("sdhn_policy", "actor"), ["robot_id:=0", "team_ns:=/bad//ns"],
                          "team_ns:"),
    "trainer-bad-team-ns": (("sdhn_train", "trainer"), ["env:=maif-tiny", "team_ns:=/9bad"],
                            "team_ns:"),
    "recorder-bad-team-ns": (("sdhn_sim", "recorder"), ["team_ns:=/a/", "output:={tmp}/r.mcap"],
                             "team_ns:"),
    "trainer-binary-config": (("sdhn_train", "trainer"),
                              ["env:=maif-tiny", "config:={tmp}/bin.yaml"], "config:"),
    "trainer-malformed-config": (("sdhn_train", "trainer"),
                                 ["env:=maif-tiny", "config:={tmp}/bad.yaml"], "config:"),
    "actor-sidecar-json-list": (("sdhn_policy", "actor"),
                                ["robot_id:=0", "weights_file:={tmp}/list.safetensors"],
                                "weights_file:"),
    "actor-payload-is-a-directory": (("sdhn_policy", "actor"),
                                     ["robot_id:=0", "weights_file:={tmp}/dir.safetensors"],
                                     "weights_file:"),
    "trainer-missing-init-from": (("sdhn_train", "trainer"),
                                  ["env:=maif-tiny", "init_from:=/nonexistent/actor.safetensors"],
                                  "init_from:"),
    "trainer-unreadable-init-from": (("sdhn_train", "trainer"),  # found by the learner offload
                                     ["env:=maif-tiny", "init_from:={tmp}/list.safetensors"],
                                     "init_from:"),
    "trainer-corrupt-checkpoint": (("sdhn_train", "trainer"),
                                   ["env:=maif-tiny", "resume:=true", "run_dir:={ckpt}"],
                                   "resume:"),
}


@pytest.fixture(scope="module")
def watcher() -> Peer:
    peer = Peer("config_watcher")
    peer.start()
    yield peer
    peer.close()


def under(peer: Peer, ns: str) -> list[str]:
    return sorted(t for t in peer.topics() if t.startswith(ns + "/"))


def test_watcher_sees_a_valid_nodes_topics(watcher: Peer) -> None:
    """Positive control: the same introspection does see a well-configured node's topics."""
    ns = "/cfg_ok"
    node = NodeProcess(node_cmd("sdhn_policy", "actor", ns, "robot_id:=0", "num_robots:=4"))
    try:
        t0 = time.monotonic()
        seen = wait_until(lambda: under(watcher, ns), 20)
        assert seen, f"no topic under {ns} seen in 20 s:\n{node.output}"
        print(f"control: {under(watcher, ns)} seen after {time.monotonic() - t0:.2f} s")
    finally:
        node.stop()


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_config_one_line_exit_2_no_topic(case: str, watcher: Peer, tmp_path: Path) -> None:
    (package, exe), params, field = CASES[case]
    ns = f"/cfg_{case.replace('-', '_')}"
    if any("{ckpt}" in p for p in params):
        run_dir = corrupt_checkpoint(tmp_path / "run")
        params = [p.replace("{ckpt}", str(run_dir)) for p in params]
    (tmp_path / "bin.yaml").write_bytes(bytes(range(256)))
    (tmp_path / "bad.yaml").write_text("ppo: {lr: [1, 2\n")
    (tmp_path / "list.safetensors").write_bytes(b"\0" * 16)
    (tmp_path / "list.json").write_text("[1, 2, 3]")
    (tmp_path / "dir.safetensors").mkdir()
    shipped = Path(__file__).resolve().parents[2] / "models" / "maif-tiny-sdhn" / "actor.json"
    (tmp_path / "dir.json").write_text(shipped.read_text())
    params = [p.replace("{tmp}", str(tmp_path)) for p in params]
    node = NodeProcess(node_cmd(package, exe, ns, *params))
    appeared: set[str] = set()
    t0 = time.monotonic()
    try:
        # A bound on a hang only: the trainer's torch import alone took 25-30 s at load 20+.
        while node.proc.poll() is None and time.monotonic() - t0 < 120:
            appeared.update(under(watcher, ns))
            time.sleep(0.01)
        end = time.monotonic() + 1.0  # late discovery of anything it made before dying
        while time.monotonic() < end:
            appeared.update(under(watcher, ns))
            time.sleep(0.02)
        code = node.stop()
    finally:
        node.stop()
    lines = [ln for ln in node.output.splitlines() if ln.strip()]
    took = time.monotonic() - t0
    assert code == 2, f"exit {code} (expected 2) after {took:.1f}s:\n{node.output}"
    assert len(lines) == 1 and field in lines[0] and "allowed" in lines[0], (
        f"expected one line naming {field!r}, got {len(lines)}:\n{node.output}")
    assert "Traceback" not in node.output
    assert not appeared, f"topics appeared before the config error: {sorted(appeared)}"
    print(f"{case}: exit 2 in {took:.1f}s: {lines[0]}")
