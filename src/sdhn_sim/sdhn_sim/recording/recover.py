"""``replay FILE --recover OUT.mcap``: what a recording holds up to its damage (a recorder killed
with SIGKILL leaves no summary, no footer and no end magic, which ``rosbags`` and ``mcap``'s
indexed reader refuse) rewritten as a complete rosbag2 MCAP file.

The messages are those :func:`sdhn_sim.recording.reader.read_recording` reads (every complete
chunk, in file order), with their schemas, channels and channel metadata (``offered_qos_profiles``,
``topic_type_hash``), times and sequence numbers; then the ``rosbag2`` metadata record rebuilt
from them (``sdhn_sim.recording.rosbag2``), the summary, the index and the end magic, written by
the ``mcap`` library. Written beside the target and renamed when complete; an existing file is
never replaced.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from sdhn_sim.recording import rosbag2
from sdhn_sim.recording.reader import Recording, copy_writer, fresh_path


@dataclass(frozen=True)
class Recovered:
    path: Path
    messages: int
    topics: int


def recover(rec: Recording, requested: Path, chunk_bytes: int = 1 << 20) -> Recovered:
    """Write the readable part of ``rec`` to ``requested`` (or ``<stem>-1.mcap``... when it
    exists); OSError if it cannot be written (nothing is left behind)."""
    target = fresh_path(requested)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.w.tmp")  # sdhn_base.litter cleans it
    records: dict[int, rosbag2.TopicRecord] = {}
    first = last = None
    try:
        with tmp.open("wb") as stream:
            writer, channel_ids = copy_writer(stream, rec, "sdhn replay --recover", chunk_bytes)
            for m in rec.messages:
                writer.add_message(channel_ids[m.channel_id], m.log_time_ns, m.data,
                                   m.publish_time_ns, m.sequence)
                first = m.log_time_ns if first is None else min(first, m.log_time_ns)
                last = m.log_time_ns if last is None else max(last, m.log_time_ns)
                if m.encoding != "cdr":
                    continue  # viz channels are no ROS topics: not in the bag metadata
                record = records.get(m.channel_id)
                if record is None:
                    meta = rec.channels[m.channel_id].metadata
                    record = records[m.channel_id] = rosbag2.TopicRecord(
                        m.topic, m.type_name, meta.get(rosbag2.QOS_KEY, "[]"),
                        meta.get(rosbag2.TYPE_HASH_KEY, ""))
                record.message_count += 1
            summary = rosbag2.BagSummary(target.name, list(records.values()), first, last)
            writer.add_metadata(rosbag2.METADATA_RECORD, {
                "serialized_metadata": rosbag2.serialized_metadata(summary),
                "ros_distro": rosbag2.ROS_DISTRO,
            })
            writer.finish()
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
    return Recovered(target, len(rec.messages), len(records))
