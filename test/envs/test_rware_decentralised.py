"""The decentralised scripted RWARE policy: it delivers from the robots' own observations."""

from __future__ import annotations

import numpy as np
import pytest

from sdhn_sim.envs import make_env
from sdhn_sim.envs.rware_batched import RwareBatchedEnv
from sdhn_sim.envs.rware_decentralised import DecentralisedPolicy
from sdhn_sim.envs.rware_scripted import RandomPolicy, run_episodes


@pytest.mark.parametrize("name", ["rware-tiny-2ag", "rware-3"])
def test_delivers_where_random_does_not(name):
    def deliveries(policy_of: object) -> list[int]:
        env = make_env(name, num_envs=2, seed=0, max_steps=250)
        assert isinstance(env, RwareBatchedEnv)
        policy = policy_of(env)  # type: ignore[operator]
        return [e.deliveries or 0 for e in run_episodes(env, policy, seed=0)]

    smart = deliveries(lambda env: DecentralisedPolicy(env.layout, env.num_robots, seed=0))
    rand = deliveries(lambda env: RandomPolicy(seed=0))
    assert min(smart) >= 2 and sum(smart) > sum(rand), (smart, rand)


def test_same_seed_same_observations_same_actions():
    """Seeded and fed the same observations (the only input it has), two policies agree step
    after step, and every action is one of rware's five."""
    env = make_env("rware-3", num_envs=2, seed=1)
    assert isinstance(env, RwareBatchedEnv)
    a, b = (DecentralisedPolicy(env.layout, 3, seed=5) for _ in range(2))
    obs, _ = env.reset()
    for _ in range(60):
        act_a, act_b = a.act(obs), b.act(obs.copy())
        np.testing.assert_array_equal(act_a, act_b)
        assert act_a.shape == (2, 3) and act_a.min() >= 0 and act_a.max() < 5
        obs = env.step(act_a).obs
