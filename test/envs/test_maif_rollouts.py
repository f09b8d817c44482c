"""MAIF invariants over random rollouts, determinism, batching and the loop reference."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sdhn_experiments.bench.envs import LoopMaif
from sdhn_sim.envs import make_env, make_single_env
from sdhn_sim.envs.maif import MaifEnv


def rollout_positions(env: MaifEnv, actions: np.ndarray):
    """Yield (before [B,N,2], after [B,N,2], finished [B]) for each step."""
    for a in actions:
        before = env.positions
        res = env.step(a)
        after = env.positions.copy()
        done = res.terminated | res.truncated
        for e in np.flatnonzero(done):
            after[e] = env.final_worlds[int(e)].positions
        yield before, after, done


@settings(max_examples=8, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    p_stay=st.floats(0.0, 0.8),
    name=st.sampled_from(["maif-tiny", "maif-10"]),
)
def test_invariants_over_random_rollouts(seed, p_stay, name):
    env = make_env(name, num_envs=3, seed=seed, max_steps=40)
    assert isinstance(env, MaifEnv)
    env.reset()
    rng = np.random.default_rng(seed)
    b, n = env.num_envs, env.num_robots
    probs = np.array([p_stay] + [(1 - p_stay) / 4] * 4)
    actions = rng.choice(5, size=(60, b, n), p=probs)
    for before, after, _ in rollout_positions(env, actions):
        for e in range(b):
            world = env.final_worlds.get(e) or env.world(e)
            obst = world.obstacles
            p, q = before[e], after[e]
            assert (np.abs(q - p).sum(axis=1) <= 1).all(), "a robot moved more than one cell"
            assert ((q >= 0) & (q < env.size)).all(), f"robot outside the grid: {q.tolist()}"
            assert not obst[q[:, 1], q[:, 0]].any(), "robot inside an obstacle"
            cells = q[:, 1] * env.size + q[:, 0]
            assert np.unique(cells).size == n, f"two robots share a cell: {q.tolist()}"
            same_prev = (q[:, None, :] == p[None, :, :]).all(axis=2)  # q_i == p_j
            swapped = same_prev & same_prev.T & ~np.eye(n, dtype=bool)
            assert not swapped.any(), "two robots swapped cells"


def test_batched_equals_independent_single_runs():
    b, steps = 3, 130
    batched = make_env("maif-tiny", num_envs=b, seed=11, max_steps=25)
    singles = [make_env("maif-tiny", num_envs=1, seed=11 + e, max_steps=25) for e in range(b)]
    obs, state = batched.reset()
    for e, s in enumerate(singles):
        o, st_ = s.reset()
        np.testing.assert_array_equal(obs[e], o[0])
        np.testing.assert_array_equal(state[e], st_[0])
    acts = np.random.default_rng(0).integers(0, 5, size=(steps, b, batched.num_robots))
    finished = 0
    for t in range(steps):
        r = batched.step(acts[t])
        finished += len(r.episodes)
        for e, s in enumerate(singles):
            q = s.step(acts[t, e][None])
            for field in ("obs", "state", "reward", "terminated", "truncated", "final_obs"):
                np.testing.assert_array_equal(
                    getattr(r, field)[e], getattr(q, field)[0], err_msg=f"{field} step {t} env {e}"
                )
            eps = [ep for ep in r.episodes if ep.env_index == e]
            assert [(x.episode_return, x.length, x.makespan) for x in eps] == [
                (x.episode_return, x.length, x.makespan) for x in q.episodes
            ]
    assert finished >= b * 4, "the run should cover several auto-resets"


def test_same_seed_same_run_and_reset_seed_restarts():
    def run(env):
        env.reset(seed=3)
        acts = np.random.default_rng(1).integers(0, 5, size=(40, 2, env.num_robots))
        return [env.step(a).obs.copy() for a in acts], env.instance_id.tolist()

    e1 = make_env("maif-10", num_envs=2, seed=99, max_steps=10)
    e2 = make_env("maif-10", num_envs=2, seed=5, max_steps=10)
    o1, i1 = run(e1)
    o2, i2 = run(e2)
    assert i1 == i2
    for a, b in zip(o1, o2, strict=True):
        np.testing.assert_array_equal(a, b)
    o3, _ = run(e1)
    np.testing.assert_array_equal(o1[-1], o3[-1])


def test_matches_per_robot_loop_reference():
    env = make_env("maif-tiny", num_envs=2, seed=4, max_steps=500)
    assert isinstance(env, MaifEnv)
    env.reset()
    refs = [LoopMaif(env.world(e), rewards=env.rewards) for e in range(2)]
    rng = np.random.default_rng(7)
    n = env.num_robots
    collisions = 0
    for t in range(150):
        # crowd the robots: mostly right/down (towards the goals) and some random moves
        toward = rng.integers(2, 5, (2, n))
        a = np.where(rng.random((2, n)) < 0.6, toward, rng.integers(0, 5, (2, n)))
        a[a == 3] = 4
        res = env.step(a)
        for e in range(2):
            obs, _team, robot_r, coll = refs[e].step(a[e].tolist())
            ctx = f"step {t} env {e}"
            want_obs = res.final_obs[e]
            np.testing.assert_allclose(want_obs, np.array(obs, np.float32), atol=1e-6, err_msg=ctx)
            np.testing.assert_allclose(env.robot_rewards[e], robot_r, atol=1e-5, err_msg=ctx)
            np.testing.assert_array_equal(env.robot_collisions[e], coll, err_msg=ctx)
            collisions += sum(coll)
            if res.terminated[e] or res.truncated[e]:
                refs[e] = LoopMaif(env.world(e), rewards=env.rewards)
    assert collisions > 20, "the rollout should exercise conflicts"


def test_instance_ids_and_round_robin():
    env = make_env("maif-tiny", num_envs=2, seed=0, max_steps=1,
                   instance_ids=[5, 17, 42], instance_order="round_robin")
    assert isinstance(env, MaifEnv)
    env.reset()
    seen = [env.instance_id.tolist()]
    for _ in range(3):
        env.step(np.zeros((2, env.num_robots), dtype=np.int64))
        seen.append(env.instance_id.tolist())
    assert seen == [[5, 17], [42, 5], [17, 42], [5, 17]], seen
    rnd = make_env("maif-tiny", num_envs=4, seed=0, max_steps=1, instance_ids=[3, 9])
    rnd.reset()
    ids = set()
    for _ in range(10):
        rnd.step(np.zeros((4, rnd.num_robots), dtype=np.int64))
        ids.update(rnd.instance_id.tolist())  # type: ignore[attr-defined]
    assert ids == {3, 9}


def test_single_env_view():
    env = make_single_env("maif-tiny", seed=2, max_steps=5)
    obs, state = env.reset()
    assert obs.shape == (4, 57) and state.shape == (228,)
    start = env.positions.copy()
    assert env.obstacles.shape == (12, 12) and env.goals.shape == (4, 2)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((1, 4), dtype=np.int64))
    for _ in range(5):
        obs, _, _, terminated, truncated, info = env.step(np.full(4, 4))
    assert truncated and not terminated and info["episode"].length == 5
    # the caller still sees the finished episode's world until reset
    assert (env.positions != start).any()
    np.testing.assert_array_equal(obs[:, 0] * 11, env.positions[:, 0])
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(4, dtype=np.int64))
    obs2, _ = env.reset()
    np.testing.assert_array_equal(obs2[:, 0] * 11, env.positions[:, 0])
    img = env.render_rgb(cell_px=6)
    assert img.shape == (72, 72, 3) and img.dtype == np.uint8
