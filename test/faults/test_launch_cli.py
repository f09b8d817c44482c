"""``python -m sdhn_bringup`` as a user drives it: a reused run directory, weights that do not
fit the environment, unreadable YAML and an unwritable run directory are each one line and exit
code 2, before any process starts; an actor that cannot act fails (exit 1), it never idles."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from .errors import one_line

REPO = Path(__file__).resolve().parents[2]
LAUNCH = [sys.executable, "-m", "sdhn_bringup"]
SHIPPED = REPO / "models" / "maif-tiny-sdhn" / "actor.safetensors"


def launch(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*LAUNCH, *args], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO, check=False)


def wrong_weights(path: Path, obs_size: int = 99) -> Path:
    from sdhn_policy.actor_torch import Actor
    from sdhn_policy.weights import ActorSpec, save_actor_file

    actor = Actor(ActorSpec(obs_size=obs_size, num_actions=5))
    save_actor_file(path, actor.export(version=1))
    return path


def test_a_reused_run_dir_is_refused(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "episodes.csv").write_text("episode\n0\n")
    r = launch("--set", f"run_dir={run}", "--set", f"weights={SHIPPED}", "--set", "episodes=1")
    assert r.returncode == 2
    assert "already holds a run" in one_line(r.stderr)
    assert sorted(p.name for p in run.iterdir()) == ["episodes.csv"]


def test_a_wrappers_own_file_does_not_make_a_run(tmp_path: Path) -> None:
    """scripts/soak.py writes its log into the run directory before it starts the launcher."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "soak-launcher.log").write_text("")
    r = launch("--set", f"run_dir={run}", "--set", f"weights={SHIPPED}", "--set", "episodes=1",
               "--set", "recorder=false", timeout=120)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr


def test_weights_that_do_not_fit_the_env_are_refused_before_start(tmp_path: Path) -> None:
    w = wrong_weights(tmp_path / "actor.safetensors")
    r = launch("--set", f"run_dir={tmp_path / 'run'}", "--set", f"weights={w}",
               "--set", "episodes=1")
    assert r.returncode == 2
    assert "does not fit" in one_line(r.stderr) and "99" in r.stderr
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("content", [bytes(range(256)), b"env: [maif-tiny\n", b"- a\n- b\n"])
def test_unreadable_yaml_is_one_line(tmp_path: Path, content: bytes) -> None:
    cfg = tmp_path / "launch.yaml"
    cfg.write_bytes(content)
    r = launch(str(cfg), "--set", f"run_dir={tmp_path / 'run'}")
    assert r.returncode == 2
    assert "config" in one_line(r.stderr)


@pytest.mark.parametrize("bad", ["/proc/sdhn-test/run", "{file}/run"])
def test_an_unwritable_run_dir_is_one_line(tmp_path: Path, bad: str) -> None:
    (tmp_path / "file").write_text("x")
    r = launch("--set", f"run_dir={bad.format(file=tmp_path / 'file')}",
               "--set", f"weights={SHIPPED}", "--set", "episodes=1")
    assert r.returncode == 2
    assert "run_dir" in one_line(r.stderr)


def test_an_actor_that_cannot_act_fails(tmp_path: Path) -> None:
    """Weights with another observation length given to the actor directly (no launcher check):
    three observations it cannot use before any answer end it with exit code 1 and one line."""
    from ros.own_node import own_node

    from sdhn_base.ros.qos import STEP
    from sdhn_msgs.msg import RobotObservation

    w = wrong_weights(tmp_path / "actor.safetensors")
    ns = "/cannot_act"
    cmd = [sys.executable, "-m", "sdhn_bringup.ros2_cli", "run", "sdhn_policy", "actor",
           "--ros-args", "-r", f"__ns:={ns}/robot_0", "-p", f"team_ns:={ns}",
           "-p", "robot_id:=0", "-p", "num_robots:=2", "-p", f"weights_file:={w}"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        with own_node("obs_sender") as node:
            pub = node.create_publisher(RobotObservation, f"{ns}/robot_0/obs", STEP)
            deadline = time.monotonic() + 60
            while pub.get_subscription_count() == 0:
                assert time.monotonic() < deadline and proc.poll() is None, "actor never subscribed"
                time.sleep(0.05)
            msg = RobotObservation()
            msg.robot_id, msg.num_robots = 0, 2
            msg.obs = [0.0] * 7
            for _ in range(3):  # as the simulator re-sends step 0 to a silent actor
                pub.publish(msg)
                time.sleep(0.2)
            _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, err
    assert "cannot act" in err and "Traceback" not in err, err


@pytest.mark.parametrize("item", ["env=[x", "episodes={a", "team_ns=/a//b", "episodes=abc"])
def test_a_bad_set_value_is_one_line(tmp_path: Path, item: str) -> None:
    r = launch("--set", item, "--set", f"weights={SHIPPED}", "--set",
               f"run_dir={tmp_path / 'run'}", "--print-config")
    assert r.returncode == 2
    assert item.split("=", maxsplit=1)[0] in one_line(r.stderr)


def test_launch_sh_takes_relative_paths_from_the_callers_directory(tmp_path: Path) -> None:
    """scripts/launch.sh used to change into the checkout, so a relative weights path (or
    run_dir, or config) named a file there, not where the user stood."""
    (tmp_path / "mine").mkdir()
    fit = tiny_fit_weights(tmp_path / "mine" / "actor.safetensors")
    r = subprocess.run([str(REPO / "scripts" / "launch.sh"), "--set", "env=maif-tiny",
                        "--set", "weights=mine/actor.safetensors", "--print-config"],
                       capture_output=True, text=True, timeout=60, cwd=tmp_path, check=False)
    assert r.returncode == 0, r.stderr
    assert f"weights: {fit.resolve()}" in r.stdout, r.stdout


def tiny_fit_weights(path: Path) -> Path:
    from sdhn_sim.envs import make_single_env

    env = make_single_env("maif-tiny", seed=0)
    return wrong_weights(path, obs_size=env.obs_size)


def test_a_weights_directory_means_its_actor_safetensors_only(tmp_path: Path) -> None:
    """A directory without actor.safetensors is refused naming what it holds; it never picks
    the last of the checkpoints or actors found anywhere below it."""
    from sdhn_bringup.launch_load import LaunchConfigError, resolve_weights

    run = tmp_path / "run"
    (run / "old" / "z").mkdir(parents=True)
    tiny_fit_weights(run / "old" / "z" / "actor.safetensors")
    with pytest.raises(LaunchConfigError, match=r"has no actor\.safetensors") as e:
        resolve_weights(str(run))
    assert "old/z/actor.safetensors" in str(e.value) and "name the file" in str(e.value)
    top = tiny_fit_weights(run / "actor.safetensors")
    assert resolve_weights(str(run)) == top


@pytest.mark.parametrize("name", ["..", ".", "../netns", "a/b", "", "x" * 65])
def test_a_hosts_entry_must_name_a_namespace(tmp_path: Path, name: str,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """``hosts.sim=..`` passed validation (``/run/netns/..`` exists) and failed at run time."""
    from sdhn_bringup import launch_load

    netns = tmp_path / "netns"
    (netns / "a").mkdir(parents=True)
    (netns / "real").touch()
    monkeypatch.setattr(launch_load, "NETNS_DIR", netns)
    ok = launch_load.load_config(None, ["mode=train", "env=maif-tiny", "hosts.sim=real"])
    assert ok.hosts == {"sim": "real"}
    with pytest.raises(launch_load.LaunchConfigError, match=r"hosts\.sim: no network namespace"):
        launch_load.load_config(None, ["mode=train", "env=maif-tiny", f"hosts.sim={name}"])


@pytest.mark.parametrize("attack", ["deep_header", "spec_infinity"])
def test_crafted_weights_are_one_line(tmp_path: Path, attack: str) -> None:
    """Deeply nested or non-finite headers once escaped as RecursionError / OverflowError."""
    from sdhn_policy.weights import decode_weights, load_actor_file

    from .crafted_weights import write_crafted_file

    good = load_actor_file(tiny_fit_weights(tmp_path / "good.safetensors"))
    decode_weights(good)
    w = write_crafted_file(tmp_path / "actor.safetensors", good, attack)
    r = launch("--set", f"run_dir={tmp_path / 'run'}", "--set", f"weights={w}",
               "--set", "env=maif-tiny", "--print-config")
    assert r.returncode == 2, r.stderr
    assert one_line(r.stderr).startswith("launch: invalid configuration: weights:"), r.stderr
