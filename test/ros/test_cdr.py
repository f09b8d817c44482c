"""The trainer's CDR readers against rclpy's own serialisation, field for field: every frame_id
and env_name length (all paddings), empty and long arrays, extreme values; malformed bytes raise
CdrError. The simulator's and actor's CDR writers against it too: same length, and rclpy decodes
them to the message it would have serialised (padding bytes are not compared: rclpy leaves them
uninitialised)."""

from __future__ import annotations

import array

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from sdhn_base.ros.cdr import (
    ActionWriter,
    CdrError,
    ObservationWriter,
    read_action,
    read_observation,
    read_state,
)
from sdhn_msgs.msg import RobotAction, RobotObservation, TeamState


def f32(a: np.ndarray) -> array.array:
    return array.array("f", np.asarray(a, np.float32).tobytes())


@pytest.mark.parametrize("frame", ["", "m", "ma", "map", "map1", "world_frame"])
@pytest.mark.parametrize("size", [0, 1, 57, 300])
def test_observation(frame: str, size: int) -> None:
    rng = np.random.default_rng(size)
    m = RobotObservation(episode=2**32 - 1, step=12345, robot_id=19, num_robots=20,
                         reward=-3.25, terminated=True, truncated=False, obs_age=size + 3)
    m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec = frame, -5, 999_999_999
    values = rng.standard_normal(size).astype(np.float32)
    m.obs = f32(values)
    o = read_observation(serialize_message(m))
    assert (o.episode, o.step, o.robot_id, o.num_robots) == (2**32 - 1, 12345, 19, 20)
    np.testing.assert_array_equal(o.obs, values)
    assert (o.reward, o.terminated, o.truncated, o.obs_age) == (-3.25, True, False, size + 3)


def test_observation_of_the_definition_before_obs_age_reads_it_as_missing() -> None:
    """A publisher built before obs_age was appended sends bytes that end at ``truncated``:
    every other field still reads, obs_age is None (the actor's dead reckoning drops it)."""
    values = np.arange(57, dtype=np.float32)
    m = RobotObservation(episode=3, step=9, robot_id=1, num_robots=4, reward=0.5,
                         truncated=True, obs_age=2, obs=f32(values))
    full = serialize_message(m)
    old = full[:-4]  # obs_age is the last 4 bytes (aligned after the two bools)
    o = read_observation(old)
    assert (o.episode, o.step, o.robot_id, o.reward, o.truncated) == (3, 9, 1, 0.5, True)
    np.testing.assert_array_equal(o.obs, values)
    assert o.obs_age is None and read_observation(full).obs_age == 2


@pytest.mark.parametrize("frame", ["", "m", "ma", "map", "map1"])
def test_action(frame: str) -> None:
    m = RobotAction(episode=7, step=8, robot_id=65535, action=255, log_prob=-0.125,
                    policy_version=2**32 - 2)
    m.header.frame_id = frame
    assert read_action(serialize_message(m)) == (7, 8, 65535, 255, -0.125, 2**32 - 2)


@pytest.mark.parametrize("env", ["", "m", "maif-tiny", "maif-20", "rware-3x"])
@pytest.mark.parametrize("size", [0, 3, 400])
def test_state(env: str, size: int) -> None:
    m = TeamState(env_name=env, episode=4, step=99, num_robots=20, team_reward=2.5,
                  terminated=False, truncated=True, makespan_so_far=99, missed_actions=3,
                  instance_id=-1)
    m.header.frame_id = "map"
    values = np.arange(size, dtype=np.float32) / 7
    m.state = f32(values)
    m.positions = array.array("i", list(range(2 * (size % 5))))
    s = read_state(serialize_message(m))
    assert (s.episode, s.step, s.num_robots) == (4, 99, 20)
    np.testing.assert_array_equal(s.state, values)
    assert (s.team_reward, s.terminated, s.truncated, s.missed_actions) == (2.5, False, True, 3)


def test_malformed_bytes_raise() -> None:
    good = serialize_message(RobotObservation(obs=f32(np.ones(57))))
    for bad in (b"", good[:20], b"\x01\x00" + good[2:], good[:-40]):
        with pytest.raises(CdrError):
            read_observation(bad)
    with pytest.raises(CdrError):
        read_action(good[:10])
    with pytest.raises(CdrError):
        read_state(good[:30])


@pytest.mark.parametrize("frame", ["", "m", "ma", "map", "map1", "world_frame"])
@pytest.mark.parametrize("size", [0, 1, 57, 300])
def test_observation_writer(frame: str, size: int) -> None:
    rng = np.random.default_rng(size)
    w = ObservationWriter(19, 20, size, frame)
    for step, (sec, ns) in enumerate([(1_796_000_000, 999_999_999), (0, 0), (2**31 - 1, 1)]):
        values = rng.standard_normal(size).astype(np.float32)
        m = RobotObservation(episode=2**32 - 1, step=step, robot_id=19, num_robots=20,
                             reward=-3.25 * step, terminated=step == 1, truncated=step == 2,
                             obs_age=[0, 2**32 - 1, 3][step])
        m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec = frame, sec, ns
        m.obs = f32(values)
        data = w.write(sec * 10**9 + ns, 2**32 - 1, step, values, reward=-3.25 * step,
                       terminated=step == 1, truncated=step == 2, obs_age=m.obs_age)
        assert len(data) == len(serialize_message(m))
        assert deserialize_message(data, RobotObservation) == m
        o = read_observation(data)  # and the readers read it
        assert (o.step, o.obs_age) == (step, m.obs_age)


@pytest.mark.parametrize("frame", ["", "m", "ma", "map", "map1"])
def test_action_writer(frame: str) -> None:
    w = ActionWriter(65535, frame)
    for k, (action, log_prob, version) in enumerate([(255, -0.125, 2**32 - 2), (0, 0.0, 0)]):
        m = RobotAction(episode=7 + k, step=8, robot_id=65535, action=action, log_prob=log_prob,
                        policy_version=version)
        m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec = frame, 5, 6 + k
        data = w.write(5 * 10**9 + 6 + k, 7 + k, 8, action=action, log_prob=log_prob,
                       policy_version=version)
        assert len(data) == len(serialize_message(m))
        assert deserialize_message(data, RobotAction) == m
