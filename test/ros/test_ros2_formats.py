"""The text the ``ros2`` verbs print, on real generated messages and real files: ros2cli's
echo YAML rules (truncation, --no-arr, --no-str, nested messages), hz's statistics, bag info's
sizes and a damaged metadata.yaml (one line, exit 2, never a traceback)."""

from __future__ import annotations

import array
import subprocess

import numpy as np
import pytest
import yaml

from sdhn_bringup.ros2_bag import file_size
from sdhn_bringup.ros2_topic import RateWindow
from sdhn_bringup.ros2_yaml import field_value, to_yaml
from sdhn_msgs.msg import PolicyWeights, RobotObservation

from .processes import ROS2


def observation() -> RobotObservation:
    msg = RobotObservation(episode=3, step=9, robot_id=1, num_robots=4, reward=-0.25)
    msg.header.frame_id = "map"
    msg.obs = array.array("f", np.arange(57, dtype=np.float32).tobytes())
    return msg


def test_echo_yaml_follows_ros2cli_rules() -> None:
    full = yaml.safe_load(to_yaml(observation(), truncate=None))
    assert list(full) == ["header", "episode", "step", "robot_id", "num_robots", "obs", "reward",
                          "terminated", "truncated", "obs_age"]
    assert full["header"] == {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": "map"}
    assert full["obs"] == list(range(57)) and full["reward"] == -0.25
    cut = yaml.safe_load(to_yaml(observation(), truncate=3))
    assert cut["obs"] == [0.0, 1.0, 2.0, "..."]
    assert yaml.safe_load(to_yaml(observation(), no_arr=True))["obs"] == "<array type: float[57]>"
    assert yaml.safe_load(to_yaml(observation(), no_str=True))["header"]["frame_id"] == (
        "<string length: <3>>")
    weights = PolicyWeights(version=2, format="x" * 200, payload=bytes(range(10)))
    w = yaml.safe_load(to_yaml(weights, truncate=128))
    assert w["format"] == "x" * 128 + "..." and w["payload"] == list(range(10)), w
    assert field_value(observation(), "header.frame_id") == "map"
    with pytest.raises(ValueError, match="no field 'nope'"):
        field_value(observation(), "header.nope")


def test_hz_statistics() -> None:
    window = RateWindow(window=3)
    assert window.report() == "no new messages"
    for t in (0.0, 0.1, 0.3, 0.4, 0.5):
        window.add(t)
    # the last 3 intervals (window 3 -> 4 times): 0.2, 0.1, 0.1
    report = window.report()
    assert report.startswith("average rate: 7.500\n\tmin: 0.100s max: 0.200s"), report
    assert report.endswith("window: 4"), report
    assert window.report() == "no new messages"


def test_bag_sizes_and_a_damaged_metadata_file(tmp_path: object) -> None:
    assert [file_size(n) for n in (512, 2048, 5 * 1024**2)] == ["512 B", "2.0 KiB", "5.0 MiB"]
    from pathlib import Path

    bag = Path(str(tmp_path)) / "bag"
    bag.mkdir()
    for text in ("rosbag2_bagfile_information: [not, a, mapping]\n",
                 "rosbag2_bagfile_information: {topics_with_message_count: [{a: 1}]}\n",
                 "rosbag2_bagfile_information: {starting_time: 5}\n", "{: [\n"):
        (bag / "metadata.yaml").write_text(text)
        done = subprocess.run([*ROS2, "bag", "info", str(bag)], capture_output=True, text=True,
                              timeout=60, check=False)
        assert done.returncode == 2 and "Traceback" not in done.stderr, (text, done.stderr)
        assert done.stderr.startswith("ros2 bag info:"), done.stderr
