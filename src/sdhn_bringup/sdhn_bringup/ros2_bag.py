"""``ros2 bag info|play|record`` for the project's MCAP recordings and rosbag2 bag directories.

- ``info BAG``: ros2 bag info's layout (files, size, storage, distro, duration, start, end,
  message count, one line per topic with type, count and serialization format), plus what
  ros2 bag info does not print: each topic's offered QoS as recorded. BAG is a bare ``.mcap``
  file (read from its summary, or message by message when the summary is missing) or a bag
  directory with ``metadata.yaml`` (read from it, as rosbag2 does).
- ``play BAG [-r RATE] [-d S] [--wait-for-all-acked MS]``: ``sdhn_sim replay FILE --rate RATE
  --wait S`` (every topic with its recorded QoS, reliable topics flow-controlled; first waits up
  to S seconds until every topic has a subscriber).
- ``record [-a] [-o OUT] [-s mcap] [--team-ns NS]``: the recorder node (``sdhn_sim
  recorder``): every topic of the team namespace into the bag directory OUT (default
  ``rosbag2_<date>-<time>`` as ros2 bag names it; a name ending ``.mcap`` is a bare file), until
  Ctrl-C. It records a team namespace, not a list of topics.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sdhn_base.yaml_io import YamlError, load_yaml
from sdhn_sim.recording.reader import NotMcapError, read_recording
from sdhn_sim.recording.rosbag2 import QOS_KEY, QosFormatError, parse_offered_qos

INDENT = 19  # ros2 bag info's label column ("Topic information: ")


@dataclass
class TopicSummary:
    name: str
    type_name: str
    count: int
    serialization: str = "cdr"
    offered_qos: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class BagInfo:
    files: list[Path]
    storage: str
    distro: str
    start_ns: int
    end_ns: int
    topics: list[TopicSummary]
    note: str = ""  # how it was read, when not the usual way

    @property
    def messages(self) -> int:
        return sum(t.count for t in self.topics)


class BagError(ValueError):
    """The path is neither an MCAP file nor a bag directory; the message says why."""


def qos_list(raw: Any) -> list[dict[str, Any]]:
    """Offered QoS profiles from a channel's metadata text or metadata.yaml (a list in version 9,
    a YAML string before)."""
    if isinstance(raw, str):
        try:
            loaded = load_yaml(raw, what="offered_qos_profiles") if raw.strip() else []
        except YamlError:
            return []
        raw = loaded
    return [p for p in raw if isinstance(p, dict)] if isinstance(raw, list) else []


def info_from_mcap(path: Path) -> BagInfo:
    """From the MCAP summary (statistics and channels); message by message if it has none."""
    from mcap.reader import make_reader

    try:
        with path.open("rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:  # a file without a readable summary (crash): count what is readable
        summary = None
    if summary is not None and summary.statistics is not None:
        stats = summary.statistics
        schemas = {s.id: s.name for s in summary.schemas.values()}
        topics: dict[str, TopicSummary] = {}
        for cid, channel in summary.channels.items():
            t = topics.setdefault(channel.topic, TopicSummary(
                channel.topic, schemas.get(channel.schema_id, ""), 0, channel.message_encoding,
                qos_list(channel.metadata.get(QOS_KEY, ""))))
            t.count += stats.channel_message_counts.get(cid, 0)
        return BagInfo([path], "mcap", "jazzy", stats.message_start_time,
                       stats.message_end_time, sorted(topics.values(), key=lambda t: t.name))
    try:
        rec = read_recording(path)
    except NotMcapError as e:
        raise BagError(str(e)) from e
    counted: dict[str, TopicSummary] = {}
    for m in rec.messages:
        channel = rec.channels[m.channel_id]
        t = counted.setdefault(m.topic, TopicSummary(
            m.topic, m.type_name, 0, m.encoding, qos_list(channel.metadata.get(QOS_KEY, ""))))
        t.count += 1
    times = [m.log_time_ns for m in rec.messages] or [0]
    note = "no summary (the recording did not finish): counted the readable messages"
    if rec.truncated is not None:
        note += f"; readable up to message {rec.truncated.messages}"
    return BagInfo([path], "mcap", "jazzy", min(times), max(times),
                   sorted(counted.values(), key=lambda t: t.name), note)


def info_from_directory(bag: Path) -> BagInfo:
    """From ``metadata.yaml``, as rosbag2 reads a bag directory; a directory without it (a
    recorder that was killed) is read from its MCAP files, and said so."""
    meta_path = bag / "metadata.yaml"
    if not meta_path.exists():
        files = sorted(bag.glob("*.mcap"))
        if not files:
            raise BagError(f"{bag}: no metadata.yaml and no .mcap file: not a bag directory")
        parts = [info_from_mcap(f) for f in files]
        merged: dict[str, TopicSummary] = {}
        for p in parts:
            for t in p.topics:
                merged.setdefault(t.name, TopicSummary(t.name, t.type_name, 0, t.serialization,
                                                       t.offered_qos)).count += t.count
        return BagInfo(files, "mcap", "jazzy", min(p.start_ns for p in parts),
                       max(p.end_ns for p in parts), sorted(merged.values(), key=lambda t: t.name),
                       "no metadata.yaml (the recorder did not stop cleanly): read the .mcap files")
    try:
        meta = load_yaml(meta_path, what="bag metadata") or {}
    except YamlError as e:
        raise BagError(str(e)) from None
    meta = meta.get("rosbag2_bagfile_information") if isinstance(meta, dict) else None
    if not isinstance(meta, dict):
        raise BagError(f"{meta_path}: no rosbag2_bagfile_information")
    start = int(meta.get("starting_time", {}).get("nanoseconds_since_epoch", 0))
    duration = int(meta.get("duration", {}).get("nanoseconds", 0))
    topics = [TopicSummary(t["topic_metadata"]["name"], t["topic_metadata"]["type"],
                           int(t.get("message_count", 0)),
                           t["topic_metadata"].get("serialization_format", "cdr"),
                           qos_list(t["topic_metadata"].get("offered_qos_profiles", [])))
              for t in meta.get("topics_with_message_count", [])]
    return BagInfo([bag / p for p in meta.get("relative_file_paths", [])],
                   str(meta.get("storage_identifier", "")), str(meta.get("ros_distro", "")),
                   start, start + duration, sorted(topics, key=lambda t: t.name))


def read_info(path: Path) -> BagInfo:
    if path.is_dir():
        try:
            return info_from_directory(path)
        except (KeyError, TypeError, AttributeError, ValueError, yaml.YAMLError) as e:
            if isinstance(e, BagError):
                raise
            raise BagError(f"{path / 'metadata.yaml'}: not rosbag2 metadata "
                           f"({type(e).__name__}: {e})") from e
    if not path.exists():
        raise BagError(f"{path}: no such file or directory")
    return info_from_mcap(path)


def file_size(n: int) -> str:
    """ros2 bag info's size: B, KiB, MiB, GiB with one decimal."""
    size = float(n)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if size < 1024 or unit == "GiB":
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1024
    return f"{size:.1f} GiB"


def time_text(ns: int) -> str:
    """``Jan  1 2024 10:00:00.123 (1704103200.123456789)``, local time, as ros2 bag info."""
    sec, frac = divmod(ns, 1_000_000_000)
    try:
        stamp = time.strftime("%b %e %Y %H:%M:%S", time.localtime(sec))
    except (OverflowError, OSError, ValueError):  # a time no calendar holds (a damaged file)
        stamp = "(out of range)"
    return f"{stamp}.{frac // 1_000_000:03d} ({sec}.{frac:09d})"


def qos_text(profile: dict[str, Any]) -> str:
    history = str(profile.get("history", "unknown"))
    depth = profile.get("depth", 0)
    return (f"{profile.get('reliability', 'unknown')}, {profile.get('durability', 'unknown')}, "
            f"{history}" + (f" ({depth})" if history == "keep_last" else ""))


def format_info(info: BagInfo) -> str:
    pad = " " * INDENT

    def block(label: str, lines: Sequence[str]) -> list[str]:
        head = f"{label}:".ljust(INDENT)
        return [head + (lines[0] if lines else "")] + [pad + line for line in lines[1:]]

    duration = max(0, info.end_ns - info.start_ns)
    size = sum(f.stat().st_size for f in info.files if f.exists())
    out = [""]
    out += block("Files", [str(f.name) for f in info.files])
    out += block("Bag size", [file_size(size)])
    out += block("Storage id", [info.storage])
    out += block("ROS Distro", [info.distro])
    out += block("Duration", [f"{duration // 1_000_000_000}.{duration % 1_000_000_000:09d}s"])
    out += block("Start", [time_text(info.start_ns)])
    out += block("End", [time_text(info.end_ns)])
    out += block("Messages", [str(info.messages)])
    out += block("Topic information", [
        f"Topic: {t.name} | Type: {t.type_name} | Count: {t.count} | "
        f"Serialization Format: {t.serialization}" for t in info.topics])
    out += block("Service", ["0"])
    out += block("Service information", [])
    out += block("Topic QoS", [
        f"Topic: {t.name} | Offered: "
        + ("; ".join(sorted({qos_text(p) for p in t.offered_qos})) or "not recorded")
        + f" | Publishers: {len(t.offered_qos)}" for t in info.topics])
    if info.note:
        out.append(f"Note: {info.note}")
    return "\n".join(out)


def mcap_of(bag: Path) -> Path:
    """The MCAP file to play: the file itself, or a bag directory's single file."""
    if not bag.is_dir():
        return bag
    files = read_info(bag).files
    if len(files) != 1:
        raise BagError(f"{bag}: {len(files)} storage files; playing a split bag is not supported")
    return files[0]


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ros2 bag")
    sub = p.add_subparsers(dest="verb", required=True)
    info = sub.add_parser("info", help="what a bag holds")
    info.add_argument("bag_path", type=Path)
    info.add_argument("-s", "--storage", default="mcap", choices=["mcap"])
    play = sub.add_parser("play", help="publish a bag's messages at their recorded pace")
    play.add_argument("bag_path", type=Path)
    play.add_argument("-r", "--rate", type=float, default=1.0)
    play.add_argument("-d", "--delay", type=float, default=2.0, metavar="S",
                      help="wait up to S seconds for every topic to have a subscriber first")
    play.add_argument("-s", "--storage", default="mcap", choices=["mcap"])
    play.add_argument("--wait-for-all-acked", type=int, default=10000, metavar="MS",
                      help="milliseconds to wait for reliable subscribers' acknowledgements")
    play.add_argument("--disable-keyboard-controls", action="store_true",
                      help="accepted for compatibility (there are no keyboard controls)")
    record = sub.add_parser("record", help="record a team namespace until Ctrl-C")
    record.add_argument("topics", nargs="*", help="not supported: the recorder records --team-ns")
    record.add_argument("-a", "--all", action="store_true",
                        help="every topic of the team namespace (the only mode)")
    record.add_argument("-o", "--output", default=None,
                        help="bag directory to write (a name ending .mcap: a bare MCAP file)")
    record.add_argument("-s", "--storage", default="mcap", choices=["mcap"])
    record.add_argument("--team-ns", default=None, help="team namespace (default /sdhn)")
    return p


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    try:
        if args.verb == "info":
            print(format_info(read_info(args.bag_path)))
            return 0
        if args.verb == "play":
            from sdhn_sim.recording import replay

            return replay.main([str(mcap_of(args.bag_path)), "--rate", str(args.rate),
                                "--wait", str(args.delay),
                                "--ack-timeout", str(args.wait_for_all_acked / 1000.0)])
    except (BagError, QosFormatError) as e:
        print(f"ros2 bag {args.verb}: {e}", file=sys.stderr)
        return 2
    return record(args)


def record(args: argparse.Namespace) -> int:
    if args.topics:
        print("ros2 bag record: recording a list of topics is not supported; the recorder "
              "records every topic of one team namespace (-a, --team-ns NS)", file=sys.stderr)
        return 2
    from sdhn_sim.recording import recorder_node

    output = args.output or time.strftime("rosbag2_%Y_%m_%d-%H_%M_%S")
    ros_args = ["ros2-bag-record", "--ros-args", "-p", f"output:={output}"]
    if args.team_ns:
        ros_args += ["-p", f"team_ns:={args.team_ns}"]
    return recorder_node.main(ros_args)


def offered_profiles(info: BagInfo, topic: str) -> list[Any]:
    """rclpy QoS profiles of a topic's recorded offers (for tests and tools)."""
    t = next(t for t in info.topics if t.name == topic)
    return parse_offered_qos(yaml.safe_dump(t.offered_qos)) if t.offered_qos else []
