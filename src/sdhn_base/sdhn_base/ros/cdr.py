"""Read the fields of the step messages straight from their CDR bytes (ROS-free; no rclpy import).

Why: the trainer node takes 2N+1 messages per team step (N = 20: 41 messages, ~3,000 a second).
Letting rclpy build a Python message for each (message, Header and Time objects, an array.array)
costs more than everything the trainer then does with it; under load the node fell behind the
loop. Its subscriptions take raw CDR (``raw=True``) and these functions read the fields at their
offsets with ``struct`` and ``np.frombuffer`` (the float arrays are views, no copy).

Layout: XCDR1, little endian (the encapsulation header ``00 01``), every primitive aligned to
its size relative to the first byte after the 4-byte encapsulation header; a string is a uint32
length (with the NUL) and its bytes; a sequence a uint32 count and its elements. The tests check
these readers against ``rclpy.serialization.serialize_message`` field for field. Malformed bytes
raise ``CdrError``.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

_U32 = struct.Struct("<I")
_IDS = struct.Struct("<IIHH")  # episode, step, robot_id, num_robots
_ACT = struct.Struct("<IIHB")  # episode, step, robot_id, action
_ACT_TAIL = struct.Struct("<fI")  # log_prob, policy_version
_OBS_TAIL = struct.Struct("<f??")  # reward, terminated, truncated
_STATE_TAIL = struct.Struct("<f??")
_STATE_END = struct.Struct("<IIi")  # makespan_so_far, missed_actions, instance_id
_LE = b"\x00\x01"


class CdrError(ValueError):
    """Bytes that are not a well-formed little-endian CDR message of the expected type."""


def _align(pos: int, n: int) -> int:
    """``pos`` is absolute (4 = first byte after the encapsulation header)."""
    return 4 + (-(-(pos - 4) // n)) * n


def _skip_string(data: bytes, pos: int) -> int:
    pos = _align(pos, 4)
    (length,) = _U32.unpack_from(data, pos)
    end = pos + 4 + length
    if end > len(data):
        raise CdrError("string runs past the end")
    return end


def _floats(data: bytes, pos: int) -> tuple[npt.NDArray[np.float32], int]:
    pos = _align(pos, 4)
    (count,) = _U32.unpack_from(data, pos)
    end = pos + 4 + 4 * count
    if end > len(data):
        raise CdrError("float32[] runs past the end")
    return np.frombuffer(data, np.float32, count, pos + 4), end


def _check(data: bytes) -> None:
    if len(data) < 16 or data[:2] != _LE:
        raise CdrError("not little-endian CDR")


class Observation(NamedTuple):
    episode: int
    step: int
    robot_id: int
    num_robots: int
    obs: npt.NDArray[np.float32]
    reward: float
    terminated: bool
    truncated: bool
    obs_age: int | None  # None: the bytes end before it (a publisher of the older definition)


class Action(NamedTuple):
    episode: int
    step: int
    robot_id: int
    action: int
    log_prob: float
    policy_version: int


class State(NamedTuple):
    episode: int
    step: int
    num_robots: int
    state: npt.NDArray[np.float32]
    team_reward: float
    terminated: bool
    truncated: bool
    missed_actions: int


def read_observation(data: bytes) -> Observation:
    """``sdhn_msgs/RobotObservation``: header, episode, step, robot_id, num_robots, obs[],
    reward, terminated, truncated, obs_age (None when the bytes end before it: the definition
    before obs_age was added; the reader of the age decides what that means)."""
    try:
        _check(data)
        pos = _skip_string(data, 12)  # after the stamp (sec, nanosec): frame_id
        pos = _align(pos, 4)
        episode, step, robot_id, num_robots = _IDS.unpack_from(data, pos)
        obs, pos = _floats(data, pos + 12)
        pos = _align(pos, 4)
        reward, terminated, truncated = _OBS_TAIL.unpack_from(data, pos)
        pos = _align(pos + _OBS_TAIL.size, 4)
        age = _U32.unpack_from(data, pos)[0] if pos + 4 <= len(data) else None
    except struct.error as e:
        raise CdrError(str(e)) from None
    return Observation(episode, step, robot_id, num_robots, obs, reward, terminated, truncated,
                       age)


def read_action(data: bytes) -> Action:
    """``sdhn_msgs/RobotAction``: header, episode, step, robot_id, action, log_prob,
    policy_version."""
    try:
        _check(data)
        pos = _align(_skip_string(data, 12), 4)
        episode, step, robot_id, action = _ACT.unpack_from(data, pos)
        log_prob, version = _ACT_TAIL.unpack_from(data, pos + 12)
    except struct.error as e:
        raise CdrError(str(e)) from None
    return Action(episode, step, robot_id, action, log_prob, version)


def read_state(data: bytes) -> State:
    """``sdhn_msgs/TeamState``: header, env_name, episode, step, num_robots, state[],
    positions[], team_reward, terminated, truncated, makespan_so_far, missed_actions,
    instance_id."""
    try:
        _check(data)
        pos = _skip_string(data, 12)  # frame_id
        pos = _align(_skip_string(data, pos), 4)  # env_name
        episode, step = struct.unpack_from("<II", data, pos)
        (num_robots,) = struct.unpack_from("<H", data, pos + 8)
        state, pos = _floats(data, pos + 10)
        pos = _align(pos, 4)
        (n_pos,) = _U32.unpack_from(data, pos)
        pos += 4 + 4 * n_pos
        team_reward, terminated, truncated = _STATE_TAIL.unpack_from(data, _align(pos, 4))
        pos = _align(_align(pos, 4) + 6, 4)
        _makespan, missed, _instance = _STATE_END.unpack_from(data, pos)
    except struct.error as e:
        raise CdrError(str(e)) from None
    return State(episode, step, num_robots, state, team_reward, terminated, truncated, missed)


# --- writers: the step messages' CDR without rclpy's message objects --------------------------
#
# Why: filling a generated message costs one checked Python setter per field and an
# array.array per observation, and rclpy then converts the object to C before serialising it.
# The step messages have a fixed layout once the frame_id and the obs length are known, so each
# publisher keeps one buffer, rewrites the changing fields in place and hands DDS the bytes
# (``Publisher.publish`` accepts serialized bytes). The bytes are also what a recording needs.
# The tests check every writer byte for byte against ``serialize_message``.

_STAMP = struct.Struct("<iI")  # header.stamp: sec (int32), nanosec (uint32)
_STEP = struct.Struct("<II")  # episode, step
_OBS_END = struct.Struct("<f??")  # reward, terminated, truncated
_ACT_BODY = struct.Struct("<IIHBxfI")  # episode, step, robot_id, action, (pad), log_prob, version
_NS = 1_000_000_000


def _header(frame_id: str) -> tuple[bytearray, int]:
    """Encapsulation, a zero stamp and ``frame_id``; (buffer, absolute end of the header)."""
    name = frame_id.encode() + b"\x00"
    buf = bytearray(_LE + b"\x00\x00" + bytes(8) + _U32.pack(len(name)) + name)
    return buf, len(buf)


def _pad(buf: bytearray, n: int) -> int:
    """Pad ``buf`` to the next multiple of ``n`` (CDR alignment); the new length."""
    end = _align(len(buf), n)
    buf.extend(bytes(end - len(buf)))
    return end


class ObservationWriter:
    """``sdhn_msgs/RobotObservation`` bytes for one robot (fixed ``robot_id``, ``num_robots``,
    ``frame_id`` and obs length), rewritten in place each step."""

    def __init__(self, robot_id: int, num_robots: int, obs_size: int,
                 frame_id: str = "map") -> None:
        buf, _ = _header(frame_id)
        self._ids = _pad(buf, 4)
        buf.extend(_IDS.pack(0, 0, robot_id, num_robots))
        _pad(buf, 4)
        buf.extend(_U32.pack(obs_size))
        self._obs = len(buf)
        buf.extend(bytes(4 * obs_size))
        self._end = _pad(buf, 4)
        buf.extend(_OBS_END.pack(0.0, False, False))
        self._age = _pad(buf, 4)
        buf.extend(_U32.pack(0))
        self._buf = buf
        self.obs = np.frombuffer(buf, np.float32, obs_size, self._obs)  # writable view into buf

    def write(self, stamp_ns: int, episode: int, step: int, obs: npt.ArrayLike, *,
              reward: float, terminated: bool, truncated: bool, obs_age: int = 0) -> bytes:
        """The message's CDR bytes (a copy: the buffer is reused on the next call)."""
        buf = self._buf
        _STAMP.pack_into(buf, 4, *divmod(stamp_ns, _NS))
        _STEP.pack_into(buf, self._ids, episode, step)
        self.obs[:] = obs
        _OBS_END.pack_into(buf, self._end, reward, terminated, truncated)
        _U32.pack_into(buf, self._age, obs_age)
        return bytes(buf)


class ActionWriter:
    """``sdhn_msgs/RobotAction`` bytes for one robot (fixed ``robot_id`` and ``frame_id``)."""

    def __init__(self, robot_id: int, frame_id: str = "") -> None:
        buf, _ = _header(frame_id)
        self._body = _pad(buf, 4)
        buf.extend(_ACT_BODY.pack(0, 0, robot_id, 0, 0.0, 0))
        self._buf = buf
        self.robot_id = robot_id

    def write(self, stamp_ns: int, episode: int, step: int, *, action: int, log_prob: float,
              policy_version: int) -> bytes:
        buf = self._buf
        _STAMP.pack_into(buf, 4, *divmod(stamp_ns, _NS))
        _ACT_BODY.pack_into(buf, self._body, episode, step, self.robot_id, action, log_prob,
                            policy_version)
        return bytes(buf)
