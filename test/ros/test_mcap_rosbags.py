"""An MCAP file written with our schemas (ros2msg + CDR) is read back by rosbags, an independent
reader, with equal field values; the schema text follows the layout Foxglove's parser requires."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from sdhn_sim.recording.writer import McapRosWriter

from .test_msgs_roundtrip import hypergraph, observation, summary, team_state, weights

TOPICS = {
    "/sdhn/robot_19/obs": observation,
    "/sdhn/state": team_state,
    "/sdhn/policy/weights": weights,
    "/sdhn/hypergraph": hypergraph,
    "/sdhn/episode": summary,
}


def test_rosbags_reads_back_every_field(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    sent = {topic: make() for topic, make in TOPICS.items()}
    with McapRosWriter(path) as writer:
        for i, (topic, message) in enumerate(sent.items()):
            writer.write(topic, message, log_time_ns=1_000 + i)

    with AnyReader([path]) as reader:
        got = {
            conn.topic: reader.deserialize(raw, conn.msgtype) for conn, _, raw in reader.messages()
        }
    assert set(got) == set(sent)
    for topic, original in sent.items():
        decoded = got[topic]
        for field in original.get_fields_and_field_types():
            if field == "header":
                continue
            a, b = getattr(original, field), getattr(decoded, field)
            if isinstance(a, str | bool | int):
                assert a == b, f"{topic}.{field}: wrote {a!r}, rosbags read {b!r}"
            else:
                np.testing.assert_allclose(
                    np.asarray(list(a) if isinstance(a, bytes) else a, dtype=np.float64),
                    np.asarray(b, dtype=np.float64),
                    rtol=1e-6,
                    err_msg=f"{topic}.{field}",
                )


def test_schema_layout_matches_ros2_recorder(tmp_path: Path) -> None:
    path = tmp_path / "state.mcap"
    with McapRosWriter(path) as writer:
        writer.write("/sdhn/state", team_state(), log_time_ns=1)
    with path.open("rb") as stream:
        schemas = make_reader(stream).get_summary().schemas.values()
    (schema,) = schemas
    text = schema.data.decode()
    assert schema.encoding == "ros2msg" and schema.name == "sdhn_msgs/msg/TeamState"
    fields = [line for line in text.splitlines() if line.strip() and not line.startswith("#")]
    assert fields[0].startswith("std_msgs/Header header"), "root definition first"
    assert "MSG: std_msgs/Header\n" in text and "MSG: builtin_interfaces/Time\n" in text
    assert "MSG: std_msgs/msg/" not in text, "nested types are spelled as the fields spell them"
    separators = [line for line in text.splitlines() if line.startswith("==")]
    assert separators and all(set(line) == {"="} for line in separators)
