"""Read sdhn MCAP recordings (no ROS graph needed): messages, truncation, episode summaries, frames.

    rec = read_recording("run.mcap")        # never raises on a damaged file: see rec.truncated
    rows = episode_rows(rec)                # EpisodeSummary messages, else recomputed from state
    frames = episode_frames(rec, 3)         # [T+1] RGB images of episode 3 (MAIF)

Reading is sequential (``mcap.stream_reader.StreamReader`` chunk by chunk), so a file whose writer
crashed (no summary section, a half-written last chunk) yields every message of every complete
chunk, and ``rec.truncated`` says where it stopped. Messages are CDR; they are decoded with
rclpy's serializer against the installed ``sdhn_msgs`` classes.

Recomputing a summary from ``TeamState`` (for episodes whose ``episode`` message is absent): length
= step of the terminal state; return = sum of ``team_reward`` over steps 1..length; completed =
terminated; makespan = length when completed; missed = sum of ``missed_actions``; policy version =
the newest version among the episode's recorded actions. Collisions and formation error are not in
TeamState, so they stay unknown (None) there.

Frames: rendered from the recorded positions on the world TeamState names: for MAIF the obstacles
and goals of instance ``instance_id`` of the environment's fixed instance set. Recordings made
before TeamState carried the id read as -1 (see ``ADDED_FIELDS``); for them, and for RWARE, the
frames show robots on a blank grid and the note says why. Nothing is inferred from positions.
"""

from __future__ import annotations

import struct
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO, NamedTuple

import numpy as np
import numpy.typing as npt
from mcap.records import Channel, Chunk, Header, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from rclpy.serialization import deserialize_message

from sdhn_base.drops import DropKind
from sdhn_base.ros import topics
from sdhn_sim.episode import EpisodeResult
from sdhn_sim.recording.schema import message_class

if TYPE_CHECKING:
    from mcap.writer import Writer as McapWriter


@dataclass(frozen=True)
class RawMessage:
    topic: str
    type_name: str  # the schema name ('sdhn_msgs/msg/TeamState', 'foxglove.SceneUpdate', ...)
    log_time_ns: int
    data: bytes
    encoding: str = "cdr"  # the channel's message encoding ('cdr', 'protobuf', 'json')
    channel_id: int = 0
    publish_time_ns: int = 0
    sequence: int = 0
    old_schema: bool = False  # recorded before a field of ADDED_FIELDS existed (see current_cdr)


@dataclass(frozen=True)
class Truncation:
    messages: int  # messages read before the damage
    last_chunk_end_ns: int | None  # log time of the last message of the last complete chunk
    last_chunk_offset: int | None  # byte offset just after the last complete chunk
    reason: str

    def line(self) -> str:
        where = ("no complete chunk" if self.last_chunk_offset is None
                 or self.last_chunk_end_ns is None else
                 f"last complete chunk at byte {self.last_chunk_offset} "
                 f"(log time {self.last_chunk_end_ns / 1e9:.3f} s)")
        return f"recording truncated after {self.messages} messages; {where} ({self.reason})"


@dataclass
class Recording:
    path: Path
    messages: list[RawMessage] = field(default_factory=list)
    truncated: Truncation | None = None
    profile: str = ""
    schemas: dict[int, Schema] = field(default_factory=dict)  # as read, to copy a recording
    channels: dict[int, Channel] = field(default_factory=dict)
    undecodable: Counter[str] = field(default_factory=Counter)  # topic -> messages skipped

    def topics(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for m in self.messages:
            counts[m.topic] = counts.get(m.topic, 0) + 1
        return counts

    def decoded(self, suffix: str, type_name: str | None = None
                ) -> Iterator[tuple[RawMessage, Any]]:
        """(raw, message) of every CDR message whose topic ends with ``suffix`` (e.g. '/state')
        and, if given, whose type is ``type_name``; viz channels (protobuf/JSON, e.g.
        '/viz/hypergraph') are never decoded here. A message of an unknown type or with
        malformed CDR is skipped and counted in ``undecodable`` (by topic)."""
        for m in self.messages:
            if m.encoding != "cdr" or not m.topic.endswith(suffix):
                continue
            if type_name is not None and m.type_name != type_name:
                self.undecodable[m.topic] += 1
                continue
            try:
                msg = decode(m)
            except Exception:  # unknown type (UnknownMessageType) or garbage CDR, from the file
                self.undecodable[m.topic] += 1
                continue
            yield m, msg


class NotMcapError(ValueError):
    """The file is not an MCAP recording at all."""


# Fields appended to a message type after recordings had been made: type -> (field, value an
# old recording means, struct format). A recording whose schema text lacks the field holds CDR
# that ends where the old definition ended; current_cdr appends the field (aligned) so the
# installed class decodes it. Old recordings thus read with instance_id = -1 ("unknown"), and
# every reader of the id treats -1 as "no world identity" instead of guessing one.
ADDED_FIELDS: dict[str, tuple[str, int, str]] = {
    "sdhn_msgs/msg/TeamState": ("instance_id", -1, "i"),
    "sdhn_msgs/msg/EpisodeSummary": ("instance_id", -1, "i"),
    "sdhn_msgs/msg/RobotObservation": ("obs_age", 0, "I"),  # before it, no latency existed
}


def lacks_added_field(type_name: str, schema_text: str) -> bool:
    """True when ``schema_text`` (a ros2msg schema) predates the field ADDED_FIELDS names."""
    added = ADDED_FIELDS.get(type_name)
    if added is None:
        return False
    root = schema_text.split("=" * 80, 1)[0]
    names = {line.split("#", 1)[0].split()[1] for line in root.splitlines()
             if len(line.split("#", 1)[0].split()) >= 2}
    return added[0] not in names


def current_cdr(m: RawMessage) -> bytes:
    """The message's CDR in the installed definition (old recordings: the added field appended)."""
    if not m.old_schema:
        return m.data
    _, value, fmt = ADDED_FIELDS[m.type_name]
    little = len(m.data) >= 2 and m.data[1] & 1  # encapsulation id: CDR_LE = 0x0001
    size = struct.calcsize(fmt)
    pad = (-(len(m.data) - 4)) % size  # alignment counts from the end of the 4-byte header
    return m.data + b"\0" * pad + struct.pack(("<" if little else ">") + fmt, value)


def decode(m: RawMessage) -> Any:
    return deserialize_message(current_cdr(m), message_class(m.type_name))


def fresh_path(path: Path) -> Path:
    """``path`` if it does not exist yet, else ``<stem>-1<suffix>``, ``-2``... (never clobber)."""
    if not path.exists():
        return path
    k = 1
    while (candidate := path.with_name(f"{path.stem}-{k}{path.suffix}")).exists():
        k += 1
    return candidate


def read_recording(path: str | Path) -> Recording:
    """Every message of every complete chunk, in file order. Raises NotMcapError only when the
    file does not even start like an MCAP file; any later damage sets ``truncated``."""
    path = Path(path)
    rec = Recording(path)
    schemas: dict[int, str] = {}
    old: set[int] = set()  # schema ids that predate a field of ADDED_FIELDS
    old_channels: set[int] = set()
    channels: dict[int, tuple[str, str, str]] = {}
    last_end: int | None = None
    last_offset: int | None = None

    def take(record: Any) -> None:
        if isinstance(record, Schema):
            schemas[record.id] = record.name
            if lacks_added_field(record.name, bytes(record.data).decode(errors="replace")):
                old.add(record.id)
            rec.schemas.setdefault(record.id, record)
        elif isinstance(record, Channel):
            channels[record.id] = (record.topic, schemas.get(record.schema_id, ""),
                                   record.message_encoding)
            if record.schema_id in old:
                old_channels.add(record.id)
            rec.channels.setdefault(record.id, record)
        elif isinstance(record, Header):
            rec.profile = record.profile
        elif isinstance(record, Message) and record.channel_id in channels:
            topic, type_name, encoding = channels[record.channel_id]
            rec.messages.append(RawMessage(topic, type_name, record.log_time, bytes(record.data),
                                           encoding, record.channel_id, record.publish_time,
                                           record.sequence, record.channel_id in old_channels))

    with path.open("rb") as stream:
        if stream.read(8) != b"\x89MCAP0\r\n":
            raise NotMcapError(f"{path} is not an MCAP file (bad magic)")
        stream.seek(0)
        reader = StreamReader(stream, emit_chunks=True, record_size_limit=1 << 31)
        try:
            for record in reader.records:
                if isinstance(record, Chunk):
                    inner = breakup_chunk(record, validate_crc=True)
                    for r in inner:
                        take(r)
                    last_end, last_offset = record.message_end_time, stream.tell()
                else:
                    take(record)
        except Exception as e:  # any damage ends the readable part, by design
            reason = type(e).__name__ + (f": {e}" if str(e) else "")
            rec.truncated = Truncation(len(rec.messages), last_end, last_offset, reason[:120])
    return rec


# --- viz channels --------------------------------------------------------------------------------


def viz_topics(rec: Recording) -> dict[str, int]:
    """Message counts of the viz channels (``/viz/...``, protobuf/JSON) the recording holds."""
    from sdhn_sim.viz.channels import is_viz_channel

    found = {c.topic: 0 for c in rec.channels.values()
             if is_viz_channel(c.topic, c.message_encoding)}
    for m in rec.messages:
        if m.topic in found and is_viz_channel(m.topic, m.encoding):
            found[m.topic] += 1
    return found


def team_namespace(rec: Recording) -> str | None:
    """The namespace of the first recorded TeamState topic ('/sdhn'), None without one."""
    for m in rec.messages:
        if m.encoding == "cdr" and m.type_name == "sdhn_msgs/msg/TeamState":
            return topics.team_of(m.topic, topics.STATE)
    return None


def team_kind(topic: str, type_name: str, encoding: str, ns: str) -> str | None:
    """'state' / 'hypergraph' / 'episode' for the team's own CDR topics of those types."""
    from sdhn_sim.viz.channels import KINDS

    kind = KINDS.get(type_name) if encoding == "cdr" else None
    if kind is None or topics.team_of(topic, kind) != ns:
        return None
    return kind


@dataclass
class VizUpgrade:
    out: Path
    copied: int
    written: dict[str, int]
    dropped: dict[str, int]
    team_ns: str | None


def copy_writer(stream: BinaryIO, rec: Recording, library: str,
                chunk_bytes: int) -> tuple[McapWriter, dict[int, int]]:
    """A started MCAP writer on ``stream`` with ``rec``'s profile, schemas and channels
    registered, and each channel's new id by its id in ``rec``: what writing a copy of a
    recording starts with (``--add-viz``, ``--recover``)."""
    from mcap.writer import CompressionType, Writer

    writer = Writer(stream, chunk_size=chunk_bytes, compression=CompressionType.ZSTD)
    writer.start(profile=rec.profile or "ros2", library=library)
    schema_ids = {old: writer.register_schema(s.name, s.encoding, s.data)
                  for old, s in rec.schemas.items()}
    channel_ids = {old: writer.register_channel(c.topic, c.message_encoding,
                                                schema_ids.get(c.schema_id, 0), dict(c.metadata))
                   for old, c in rec.channels.items()}
    return writer, channel_ids


def write_with_viz(rec: Recording, out: Path, chunk_bytes: int = 256 * 1024) -> VizUpgrade:
    """Write ``out``: every message of ``rec`` (same schemas, channels, times, sequence numbers,
    in file order) plus the viz channels derived from the team's state, hypergraph and episode
    messages (``sdhn_sim.viz.channels``), each right after its source message."""
    from sdhn_sim.viz.channels import VizDeriver, VizMcapChannels

    ns = team_namespace(rec)
    deriver = VizDeriver()
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("wb") as stream:
        writer, channel_ids = copy_writer(stream, rec, "sdhn replay --add-viz", chunk_bytes)
        viz = VizMcapChannels(writer)
        for m in rec.messages:
            writer.add_message(channel_ids[m.channel_id], m.log_time_ns, m.data,
                               m.publish_time_ns, m.sequence)
            kind = team_kind(m.topic, m.type_name, m.encoding, ns) if ns else None
            if kind is None:
                continue
            try:
                msg = decode(m)
            except Exception:  # malformed CDR: counted like any message that cannot be drawn
                deriver.dropped[f"{kind}/{DropKind.UNDECODABLE}"] += 1
                continue
            viz.write(deriver.derive(kind, msg, m.log_time_ns))
        writer.finish()
    return VizUpgrade(out, len(rec.messages), dict(deriver.written), dict(deriver.dropped), ns)


# --- episode summaries ---------------------------------------------------------------------------


class EpisodeRow(NamedTuple):
    """One finished episode of a recording and where its figures came from."""

    result: EpisodeResult
    source: str  # "episode" (the simulator's summary) or "state" (recomputed; no collisions)


def summaries_from_messages(rec: Recording) -> dict[int, EpisodeResult]:
    rows = {}
    for _, m in rec.decoded(f"/{topics.EPISODE}", "sdhn_msgs/msg/EpisodeSummary"):
        r = EpisodeResult.from_message(m)
        rows[r.episode] = r
    return rows


def summaries_from_states(rec: Recording) -> dict[int, EpisodeResult]:
    """Episodes whose terminal TeamState was recorded, recomputed from the states (see above)."""
    steps: dict[int, dict[int, Any]] = {}
    for _, s in rec.decoded(f"/{topics.STATE}", "sdhn_msgs/msg/TeamState"):
        steps.setdefault(int(s.episode), {})[int(s.step)] = s
    versions: dict[int, int] = {}
    for _, a in rec.decoded(f"/{topics.ACTION}", "sdhn_msgs/msg/RobotAction"):
        versions[int(a.episode)] = max(versions.get(int(a.episode), 0), int(a.policy_version))
    rows = {}
    for episode, by_step in steps.items():
        last = by_step[max(by_step)]
        if not (last.terminated or last.truncated):
            continue  # the recording ended inside this episode
        length = int(last.step)
        rewards = [float(by_step[t].team_reward) for t in range(1, length + 1) if t in by_step]
        missed = sum(int(by_step[t].missed_actions) for t in range(1, length + 1) if t in by_step)
        completed = bool(last.terminated)
        rows[episode] = EpisodeResult(
            env_name=str(last.env_name), episode=episode, length=length, completed=completed,
            makespan=length if completed else None, episode_return=float(np.sum(rewards)),
            collisions=None, formation_error=None, missed_actions=missed,
            policy_version=versions.get(episode, 0), instance_id=int(last.instance_id))
    return rows


def episode_rows(rec: Recording) -> list[EpisodeRow]:
    """One row per finished episode: the simulator's summary where recorded, else recomputed."""
    rows = {k: EpisodeRow(r, "state") for k, r in summaries_from_states(rec).items()}
    rows.update({k: EpisodeRow(r, "episode") for k, r in summaries_from_messages(rec).items()})
    return [rows[k] for k in sorted(rows)]


def format_rows(rows: list[EpisodeRow]) -> str:
    head = (f"{'episode':>7} {'length':>6} {'done':>5} {'makespan':>8} {'return':>10} "
            f"{'collisions':>10} {'missed':>6} {'version':>7}  source")
    lines = [head]
    for r, source in rows:
        lines.append(
            f"{r.episode:>7} {r.length:>6} {'yes' if r.completed else 'no':>5} "
            f"{r.makespan_text:>8} {r.episode_return:>10.3f} "
            f"{r.collisions if r.collisions is not None else '-':>10} {r.missed_actions:>6} "
            f"{r.policy_version:>7}  {source}")
    return "\n".join(lines)


# --- frames --------------------------------------------------------------------------------------


@dataclass
class EpisodeFrames:
    episode: int
    steps: list[int]
    images: list[npt.NDArray[np.uint8]]
    map_note: str


def maif_world(env_name: str, instance_id: int
               ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.int64]] | None:
    """(obstacles, goals) of MAIF instance ``instance_id`` of ``env_name``; None when the
    environment has no numbered instances or the id is unknown (-1) or out of range."""
    from sdhn_sim.envs.maif_instances import MAIF_CONFIGS, load_instances

    if env_name not in MAIF_CONFIGS or instance_id < 0:
        return None
    inst = load_instances(env_name)
    if instance_id >= inst.num_instances:
        return None
    obstacles, _, goals = inst.instance(instance_id)
    return obstacles.astype(bool), goals


@dataclass
class EpisodeStates:
    """The recorded TeamStates of one episode, by step."""

    env_name: str
    instance_id: int
    steps: list[int]
    positions: npt.NDArray[np.int64]  # [T, N, 2] grid cells (x, y)
    log_times: list[int]  # ns, when the recorder received each state
    dropped: int = 0  # recorded states left out: positions not [N, 2] cells on the map


MAX_BLANK_GRID = 256
"""Largest grid side drawn for an episode whose map is unknown (cells); MAIF's largest is 60."""


def episode_states(rec: Recording, episode: int) -> EpisodeStates:
    """The TeamStates of ``episode`` whose positions are [N, 2] cells in [0, MAX_BLANK_GRID)
    with the first state's N (others are counted in ``dropped``, as --add-viz drops them);
    KeyError if none was recorded or none is usable."""
    recorded = rec.decoded(f"/{topics.STATE}", "sdhn_msgs/msg/TeamState")
    states = sorted(((int(s.step), raw.log_time_ns, s) for raw, s in recorded
                     if int(s.episode) == episode), key=lambda x: x[0])
    kept: list[tuple[int, int, Any, npt.NDArray[np.int64]]] = []
    for step, log_time, s in states:
        flat = np.frombuffer(s.positions, dtype=np.int32).astype(np.int64)
        if flat.size == 0 or flat.size % 2 or (kept and flat.size != kept[0][3].size) or (
                flat.min() < 0 or flat.max() >= MAX_BLANK_GRID):
            continue
        kept.append((step, log_time, s, flat.reshape(-1, 2)))
    if not kept:
        raise KeyError(episode)
    first = kept[0][2]
    return EpisodeStates(str(first.env_name), int(first.instance_id), [t for t, _, _, _ in kept],
                         np.stack([p for _, _, _, p in kept]), [lt for _, lt, _, _ in kept],
                         dropped=len(states) - len(kept))


def on_map(st: EpisodeStates, obstacles: npt.NDArray[np.bool_]) -> EpisodeStates:
    """``st`` without the states that put a robot outside ``obstacles`` (counted in
    ``dropped``); KeyError if none is left."""
    rows, cols = obstacles.shape
    inside = ((st.positions[..., 0] < cols) & (st.positions[..., 1] < rows)).all(axis=1)
    if not inside.any():
        raise KeyError("no recorded state is on the map")
    if inside.all():
        return st
    keep = np.flatnonzero(inside)
    return EpisodeStates(st.env_name, st.instance_id, [st.steps[i] for i in keep],
                         st.positions[keep], [st.log_times[i] for i in keep],
                         dropped=st.dropped + int((~inside).sum()))


def episode_map(env_name: str, k: int, positions: npt.NDArray[np.int64]
                ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.int64] | None, str]:
    """(obstacles, goals or None, a note saying where the map came from) of an episode of
    ``env_name`` on instance ``k``; a blank grid around ``positions`` when the map is unknown."""
    found = maif_world(env_name, k)
    if found is not None:
        obstacles, goals = found
        return obstacles, goals, f"map: {env_name} instance {k} (from TeamState.instance_id)"
    size = int(positions.max()) + 1 if positions.size else 1
    maif = env_name.startswith("maif")
    why = ("the recording predates TeamState.instance_id" if maif and k < 0 else
           f"instance {k} is not in the installed {env_name} set" if maif else
           f"{env_name} has no numbered instances")
    return np.zeros((size, size), bool), None, f"map: unknown ({why}); robots on a blank grid"


def episode_frames(rec: Recording, episode: int, cell_px: int = 16) -> EpisodeFrames:
    """One RGB image per recorded TeamState of ``episode`` (KeyError if none was recorded)."""
    from sdhn_sim.envs.render import render_grid

    st = episode_states(rec, episode)
    obstacles, goals, note = episode_map(st.env_name, st.instance_id, st.positions)
    st = on_map(st, obstacles)
    images = [render_grid(obstacles, p, goals, cell_px) for p in st.positions]
    return EpisodeFrames(episode, st.steps, images, note + dropped_note(st))


def dropped_note(st: EpisodeStates) -> str:
    return (f"; {st.dropped} recorded states left out (positions off the map or malformed)"
            if st.dropped else "")
