"""A realistic stream of sdhn messages for tests, made from the real MAIF env without the ROS sim:
lock-step frames (obs, state, actions with log-probs) and episode summaries, exactly as the
simulator and actors would publish them."""

from __future__ import annotations

import array
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from sdhn_base.ros import topics
from sdhn_msgs.msg import (
    EpisodeSummary,
    Hypergraph,
    PolicyWeights,
    RobotAction,
    RobotObservation,
    TeamState,
)
from sdhn_sim.envs import make_single_env
from sdhn_sim.episode import EpisodeResult

ENV = "maif-tiny"


@dataclass
class Out:
    topic: str  # relative to the team namespace
    message: object


def floats(a: np.ndarray) -> array.array:
    return array.array("f", np.ascontiguousarray(a, np.float32).tobytes())


def team_stream(episodes: int, max_steps: int, seed: int = 0, version: int = 1) -> Iterator[Out]:
    """Per step: N obs + state, then N actions (none on the terminal step); then a summary."""
    env = make_single_env(ENV, seed=seed, max_steps=max_steps)
    rng = np.random.default_rng(seed)
    n = env.num_robots
    for e in range(episodes):
        obs, state = env.reset()
        instance = env.instance_id
        reward, term, trunc, t, ret = 0.0, False, False, 0, 0.0
        while True:
            positions = np.asarray(env.positions, np.int32).reshape(-1)
            for i in range(n):
                yield Out(topics.robot_obs(i), RobotObservation(
                    episode=e, step=t, robot_id=i, num_robots=n, obs=floats(obs[i]),
                    reward=reward, terminated=term, truncated=trunc))
            yield Out(topics.STATE, TeamState(
                env_name=ENV, episode=e, step=t, num_robots=n, state=floats(state),
                positions=array.array("i", positions.tobytes()), team_reward=reward,
                terminated=term, truncated=trunc, makespan_so_far=t, missed_actions=0,
                instance_id=instance))
            if term or trunc:
                break
            actions = rng.integers(0, env.num_actions, n)
            for i in range(n):
                yield Out(topics.robot_action(i), RobotAction(
                    episode=e, step=t, robot_id=i, action=int(actions[i]),
                    log_prob=float(np.log(1 / env.num_actions)), policy_version=version))
            res = env.step(actions)
            obs, state, reward = res.obs, res.state, res.reward
            term, trunc = res.terminated, res.truncated
            ret += reward
            t += 1
        ep = res.info["episode"]
        result = EpisodeResult.from_stats(ep, env_name=ENV, episode=e, missed_actions=0,
                                          policy_version=version, instance_id=instance)
        yield Out(topics.EPISODE, result.to_message(EpisodeSummary()))


def weights_message(version: int) -> PolicyWeights:
    payload = bytes(range(256)) * 64
    import hashlib

    m = PolicyWeights(version=version, format="sdhn-actor/1",
                      sha256=hashlib.sha256(payload).hexdigest())
    m.payload = payload
    return m


def hypergraph_message(step: int, n: int = 4, m: int = 10) -> Hypergraph:
    msg = Hypergraph(episode=0, step=step, num_robots=n, num_hyperedges=m, skewness=0.1,
                     policy_version=1)
    msg.p_h = floats(np.full(n * m, 0.5))
    msg.incidence = bytes([1, 0] * (n * m // 2))
    return msg
