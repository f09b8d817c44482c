"""``ros2 bag info`` reads files from outside: a seeded fuzz of damaged MCAP files (cut, bytes
flipped, in the summary or the data) and of metadata.yaml contents. Each either gives a report
or a ``BagError`` (one line, exit 2 on the command line), never another exception."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from sdhn_bringup.ros2_bag import BagError, format_info, read_info

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "maif-tiny-pre-instance-id.mcap"
CASES = 150


def report_or_bag_error(path: Path) -> str:
    try:
        return format_info(read_info(path))
    except BagError as e:
        return f"BagError: {e}"


def test_damaged_mcap_files(tmp_path: Path) -> None:
    data = FIXTURE.read_bytes()
    rng = np.random.default_rng(57)
    reports = 0
    for case in range(CASES):
        buf = bytearray(data)
        kind = case % 3
        if kind == 0:  # cut anywhere (a recorder killed mid-write)
            buf = buf[: int(rng.integers(0, len(buf)))]
        elif kind == 1:  # flipped bytes anywhere
            for i in rng.integers(0, len(buf), size=int(rng.integers(1, 20))):
                buf[int(i)] ^= int(rng.integers(1, 256))
        else:  # flipped bytes in the summary section at the end (statistics, channels)
            for i in rng.integers(max(0, len(buf) - 2000), len(buf), size=8):
                buf[int(i)] ^= int(rng.integers(1, 256))
        path = tmp_path / f"case{case}.mcap"
        path.write_bytes(bytes(buf))
        text = report_or_bag_error(path)
        reports += text.startswith("\nFiles:")
    assert reports > CASES // 3, reports  # most damaged files still give a report


def test_odd_metadata_yaml(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    leaves: list[object] = [None, -1, 2**70, "x", 1.5, [], {}, [1, "a"], {"nanoseconds": "z"},
                            {"nanoseconds_since_epoch": -(2**63)}, True]
    keys = ["starting_time", "duration", "topics_with_message_count", "relative_file_paths",
            "storage_identifier", "ros_distro", "message_count"]
    bag = tmp_path / "bag"
    bag.mkdir()
    outcomes = set()
    for _case in range(CASES):
        info = {k: leaves[int(rng.integers(len(leaves)))] for k in keys if rng.random() < 0.7}
        if rng.random() < 0.5:
            info["topics_with_message_count"] = [
                {"topic_metadata": {"name": leaves[int(rng.integers(len(leaves)))],
                                    "type": "std_msgs/msg/String",
                                    "offered_qos_profiles": leaves[int(rng.integers(len(leaves)))]},
                 "message_count": leaves[int(rng.integers(len(leaves)))]}]
        (bag / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))
        outcomes.add(report_or_bag_error(bag).split(":")[0])
    assert outcomes == {"\nFiles", "BagError"}, outcomes  # both kinds of input were generated
