"""The RWARE adapter against raw rware 2.0.0 stepping."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import rware  # noqa: F401

from sdhn_sim.envs import make_env
from sdhn_sim.envs.rware_env import RwareEnv


@pytest.mark.parametrize(("name", "n"), [("rware-3", 3), ("rware-6", 6)])
@pytest.mark.filterwarnings("ignore:.*reward returned by")
def test_adapter_matches_raw_rware(name, n):
    b, steps, limit = 2, 45, 20
    env = make_env(name, num_envs=b, seed=5, max_steps=limit, backend="rware")
    assert isinstance(env, RwareEnv) and env.env_id == f"rware-small-{n}ag-v2"
    raws = [gym.make(env.env_id, max_steps=limit) for _ in range(b)]
    obs, state = env.reset()
    assert obs.shape == (b, n, env.obs_size) and obs.dtype == np.float32
    assert state.shape == (b, n * env.obs_size)
    for e, raw in enumerate(raws):
        o, _ = raw.reset(seed=5 + e)
        np.testing.assert_array_equal(obs[e], np.stack(o))
    acts = np.random.default_rng(0).integers(0, 5, size=(steps, b, n))
    reward_seen = False
    for t in range(steps):
        res = env.step(acts[t])
        for e, raw in enumerate(raws):
            o, r, te, tr, _ = raw.step(tuple(acts[t, e].tolist()))
            ctx = f"step {t} env {e}"
            np.testing.assert_array_equal(res.final_obs[e], np.stack(o), err_msg=ctx)
            assert res.reward[e] == pytest.approx(sum(r)), ctx
            reward_seen |= sum(r) != 0
            time_up = (t + 1) % limit == 0
            assert bool(te or tr) == time_up, ctx
            # rware says terminated at the step limit; the adapter says truncated
            assert (bool(res.terminated[e]), bool(res.truncated[e])) == (False, time_up), ctx
            if time_up:
                o2, _ = raw.reset()
                np.testing.assert_array_equal(res.obs[e], np.stack(o2), err_msg=ctx)
                (ep,) = [x for x in res.episodes if x.env_index == e]
                assert ep.length == limit and ep.makespan is None
            else:
                np.testing.assert_array_equal(res.obs[e], res.final_obs[e])


def test_rware_9_and_bad_actions():
    env = make_env("rware-9", num_envs=1, seed=0)
    obs, _ = env.reset()
    assert obs.shape[1] == 9 and env.max_steps == 500
    with pytest.raises(ValueError, match="actions"):
        env.step(np.full((1, 9), 5))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((1, 8), dtype=np.int64))
