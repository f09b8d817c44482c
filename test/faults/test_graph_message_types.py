"""Message type names from outside (``ros2 topic echo TOPIC TYPE`` on the command line, or a type
any participant advertises on the graph) against ``sdhn_base.ros.graph.message_class``: only the
interface packages this project's graphs carry are ever imported; any other name is refused in
one line naming the field, the value and what is allowed, before an import. A module named by
the input that sits on sys.path (the working directory, with ``python -m``) never runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sdhn_base.ros.graph import GRAPH_MESSAGE_PACKAGES, check_message_type, message_class

REPO = Path(__file__).resolve().parents[2]
ROS2 = str(REPO / "scripts" / "ros2")

# A module of each kind a hostile name could reach: a plain module, a package shaped like an
# interface package, and installed interface packages that none of our graphs carry.
HOSTILE = ["evilmod/msg/Boom", "evilmod/Boom", "evilpkg/msg/Boom", "evilpkg/Boom",
           "os/msg/system", "subprocess/msg/Popen", "subprocess/Popen", "this/msg/X",
           "nav_msgs/msg/Odometry", "sensor_msgs/Image", "sdhn_msgs.msg/TeamState",
           "sdhn_msgs/srv/TeamState", "sdhn_msgs/msg/__class__", "../sdhn_msgs/msg/TeamState",
           "", "/", "sdhn_msgs", "sdhn_msgs/msg/TeamState/x"]


def plant(where: Path) -> Path:
    """A plain module and an interface-shaped package on ``where`` that leave a marker file
    when imported; the marker's path."""
    marker = where / "PWNED"
    run = f"open({str(marker)!r}, 'w').write('ran')\n"
    (where / "evilmod.py").write_text(run)
    (where / "evilpkg").mkdir()
    (where / "evilpkg" / "__init__.py").write_text(run)
    (where / "evilpkg" / "msg.py").write_text(run + "class Boom:\n    pass\n")
    return marker


@pytest.mark.parametrize("type_name", HOSTILE)
def test_a_name_outside_the_allowlist_is_refused_before_any_import(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        type_name: str) -> None:
    marker = plant(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    before = set(sys.modules)
    with pytest.raises(ValueError) as refused:
        message_class(type_name, "message_type")
    assert set(sys.modules) == before, sorted(set(sys.modules) - before)
    assert not marker.exists(), f"{type_name}: a module named by the input ran"
    assert capsys.readouterr().out == ""  # `this` prints the Zen of Python on import
    text = str(refused.value)
    assert "\n" not in text and text.startswith("message_type: "), text
    assert repr(type_name) in text, text
    assert (text.endswith("allowed: " + ", ".join(GRAPH_MESSAGE_PACKAGES))
            or text.endswith("expected pkg/msg/Type")), text


@pytest.mark.parametrize("type_name", ["sdhn_msgs/msg/TeamState", "sdhn_msgs/RobotAction",
                                       "std_msgs/msg/String", "geometry_msgs/msg/PoseArray",
                                       "diagnostic_msgs/msg/DiagnosticArray",
                                       "lifecycle_msgs/msg/TransitionEvent",
                                       "rcl_interfaces/msg/Log",
                                       "rcl_interfaces/msg/ParameterEvent"])
def test_the_types_our_graphs_carry_are_found(type_name: str) -> None:
    """Our own topics, the standard streams our nodes publish and every rclpy node's /rosout
    and /parameter_events."""
    cls = message_class(type_name)
    package, name = check_message_type(type_name)
    assert cls.__name__ == name and cls.__module__.startswith(f"{package}.msg"), cls


def test_an_allowed_package_without_the_type_is_one_line() -> None:
    with pytest.raises(ValueError, match=r"^message type: 'sdhn_msgs/msg/Nope' is not installed "
                                         r"here \(sdhn_msgs has no message 'Nope'\)$"):
        message_class("sdhn_msgs/msg/Nope")


def _mutant(rng: np.random.Generator) -> str:
    """A valid name, one damaged, a hostile one, or random characters from the name alphabet."""
    valid = ["sdhn_msgs/msg/TeamState", "std_msgs/String", "rcl_interfaces/msg/Log"]
    alphabet = [*"abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_/./..", "msg",
                "srv", "_msgs", "\n", " ", "\x00", "é", "Ω", "/msg/", "os", "sys", "evilmod"]
    kind = int(rng.integers(4))
    if kind == 3:
        return valid[int(rng.integers(len(valid)))]
    if kind == 0:
        chars = list(valid[int(rng.integers(len(valid)))])
        for _ in range(int(rng.integers(1, 4))):
            at = int(rng.integers(len(chars) + 1))
            if rng.random() < 0.5 and chars:
                del chars[min(at, len(chars) - 1)]
            else:
                chars.insert(at, alphabet[int(rng.integers(len(alphabet)))])
        return "".join(chars)
    if kind == 1:
        return HOSTILE[int(rng.integers(len(HOSTILE)))]
    return "".join(alphabet[int(rng.integers(len(alphabet)))]
                   for _ in range(int(rng.integers(0, 40))))


def test_seeded_fuzz_of_type_names(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every name either gives a class of an allowed package or one line of ValueError; only
    allowed packages' modules are ever imported, and no planted module runs."""
    marker = plant(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    rng = np.random.default_rng(144)
    outcomes = {"class": 0, "refused": 0}
    before = set(sys.modules)
    for _case in range(600):
        name = _mutant(rng)
        try:
            cls = message_class(name)
        except ValueError as e:
            assert "\n" not in str(e) and str(e).startswith("message type: "), (name, str(e))
            outcomes["refused"] += 1
            continue
        assert isinstance(cls, type) and cls.__module__.split(".")[0] in GRAPH_MESSAGE_PACKAGES
        outcomes["class"] += 1
    added = {m.split(".")[0] for m in set(sys.modules) - before}
    assert added <= set(GRAPH_MESSAGE_PACKAGES), sorted(added)
    assert not marker.exists()
    assert outcomes["class"] > 0 and outcomes["refused"] > 0, outcomes  # both kinds came up


@pytest.mark.parametrize("type_name", ["evilmod/msg/Boom", "evilpkg/Boom", "nav_msgs/Odometry"])
def test_ros2_topic_echo_refuses_a_type_before_a_node_starts(tmp_path: Path,
                                                              type_name: str) -> None:
    """As a user runs it (``scripts/ros2``: ``python -m``, the working directory on sys.path).
    Without the check the explicit type would be subscribed to and echo would wait for a
    publisher until the timeout."""
    marker = plant(tmp_path)
    done = subprocess.run([ROS2, "topic", "echo", "/sdhn/state", type_name], cwd=tmp_path,
                          capture_output=True, text=True, timeout=30, check=False)
    assert done.returncode == 2, (done.returncode, done.stderr)
    package = type_name.partition("/")[0]
    assert done.stderr.strip().splitlines() == [
        f"ros2 topic echo: error: message_type: {type_name!r} is in package "
        f"{package!r}, not one this project's graphs carry; allowed: "
        + ", ".join(GRAPH_MESSAGE_PACKAGES)], done.stderr
    assert not marker.exists()
