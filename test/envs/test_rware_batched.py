"""The NumPy RWARE (``RwareBatchedEnv``) against the real ``rware`` 2.0.0, step for step.

Both are seeded alike (env b from seed s + b), so the request refills and the resets draw the
same numbers from the same generators; every step compares observations, per-robot rewards,
dones, robot cells and directions, carried shelves, shelf cells and the request queue.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sdhn_experiments.bench.rware_equality import rollout
from sdhn_sim.envs import make_env
from sdhn_sim.envs.rware_batched import RwareBatchedEnv, make_layout
from sdhn_sim.envs.rware_env import RwareEnv

pytestmark = pytest.mark.filterwarnings("ignore:.*reward returned by")


@pytest.mark.parametrize(("n", "size"), [(2, "tiny"), (4, "tiny"), (3, "small"), (6, "small"),
                                         (9, "small")])
def test_random_rollouts_equal_rware(n, size):
    rollout(n, size, 120, seed=11, forward=0.5, max_steps=50)


@pytest.mark.parametrize(("n", "size", "num_envs"), [(2, "tiny", 2), (4, "tiny", 1),
                                                     (3, "small", 1), (9, "small", 1)])
def test_scripted_rollouts_equal_rware(n, size, num_envs):
    """The scripted policy fetches and delivers: loads, deliveries, refills, queueing at the
    goals, the request queue's replacement order."""
    bat = rollout(n, size, 130, seed=3, scripted=True, num_envs=num_envs)
    assert bat._deliveries.sum() > 0, "no delivery: the test did not test them"


def test_crowded_conflicts_and_ties_equal_rware():
    """A crowded tiny warehouse with mostly FORWARD: chains, cycles, swaps, and ties between
    equally long chains (the networkx path) all occur and all match."""
    bat = rollout(16, "tiny", 100, seed=2, forward=0.7, num_envs=2)
    assert bat.ties_resolved_by_networkx > 0, "no tie seen: the tie path went untested"


@pytest.mark.parametrize("difficulty", ["easy", "hard"])
def test_difficulties_and_medium_layout_equal_rware(difficulty):
    rollout(4, "medium", 60, seed=7, difficulty=difficulty, forward=0.5, max_steps=25)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), n=st.integers(1, 10),
       size=st.sampled_from(["tiny", "small"]), forward=st.floats(0.1, 0.9))
def test_property_any_seed_equal_rware(seed, n, size, forward):
    rollout(n, size, 25, seed=seed, num_envs=1, forward=forward, max_steps=12)


def test_layout_matches_rware():
    real = RwareEnv(3, size="medium").warehouses[0]
    lay = make_layout(2, 5)
    np.testing.assert_array_equal(lay.highway, real.highways.astype(bool))
    assert list(lay.goals) == [tuple(g) for g in real.goals]


@pytest.mark.parametrize(("name", "n", "size"), [("rware-3", 3, "small"), ("rware-9", 9, "small"),
                                                  ("rware-tiny-2ag", 2, "tiny"),
                                                  ("rware-tiny-4ag", 4, "tiny")])
def test_registry_builds_batched_by_default_and_rware_on_request(name, n, size):
    fast = make_env(name, num_envs=2, seed=4)
    real = make_env(name, num_envs=2, seed=4, backend="rware")
    assert isinstance(fast, RwareBatchedEnv) and isinstance(real, RwareEnv)
    assert fast.env_id == real.env_id == f"rware-{size}-{n}ag-v2"
    assert (fast.num_robots, fast.obs_size, fast.state_size) == (n, 71, n * 71)
    np.testing.assert_array_equal(fast.reset()[0], real.reset()[0])


def test_bad_input_is_refused():
    env = RwareBatchedEnv(3, num_envs=2)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros((2, 3), dtype=np.int64))
    env.reset()
    with pytest.raises(ValueError, match="actions"):
        env.step(np.full((2, 3), 5))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((2, 2), dtype=np.int64))
    with pytest.raises(ValueError, match="size"):
        RwareBatchedEnv(3, size="huge")


def test_simulator_and_viewer_see_the_tiny_tasks():
    """The simulator's single-env view reads robot cells from the batched env; the viewer's
    static description of a tiny task is rware's tiny floor."""
    from sdhn_sim.envs import make_single_env
    from sdhn_sim.viz.world import world_info

    single = make_single_env("rware-tiny-4ag", seed=3)
    single.reset()
    real = make_env("rware-tiny-4ag", num_envs=1, seed=3, backend="rware")
    real.reset()
    assert isinstance(real, RwareEnv)
    np.testing.assert_array_equal(single.positions, real.positions[0])
    info = world_info("rware-tiny-4ag")
    assert (info.num_robots, info.width, info.height) == (4, 10, 11)
    assert info.rware_racks is not None and info.rware_racks.sum() == make_layout(1, 3).num_shelves


def test_checkpoint_snapshot_resumes_exactly():
    """The trainer's generic env snapshot (arrays, scalars, generators) restores a batched
    RWARE mid-episode so that it continues exactly like the original: resumed runs equal
    uninterrupted ones."""
    from sdhn_train.checkpoint import env_restore, env_snapshot

    acts = np.random.default_rng(0).choice(5, size=(80, 3, 4), p=[.1, .6, .1, .1, .1])
    a = RwareBatchedEnv(4, num_envs=3, seed=9, size="tiny", max_steps=30)
    a.reset()
    for t in range(40):
        a.step(acts[t])
    arrays, values = env_snapshot(a)
    b = RwareBatchedEnv(4, num_envs=3, seed=123, size="tiny", max_steps=30)
    b.reset()
    env_restore(b, {k: v.copy() for k, v in arrays.items()}, values)
    for t in range(40, 80):
        ra, rb = a.step(acts[t]), b.step(acts[t])
        np.testing.assert_array_equal(ra.obs, rb.obs, err_msg=f"step {t}")
        np.testing.assert_array_equal(ra.reward, rb.reward, err_msg=f"step {t}")
        assert ra.episodes == rb.episodes, t
