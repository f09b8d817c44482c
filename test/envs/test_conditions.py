"""The deployment-condition model (sdhn_sim.envs.conditions): validation, ideal == identity,
seeded determinism, each condition's effect, per-env reset, and that the in-process wrapper and
the simulator's lock-step core give the same outcomes for the same seeds."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.dead_reckoning import DeadReckoner
from sdhn_sim.envs import make_env
from sdhn_sim.envs.conditions import (
    ConditionedEnv,
    ConditionModel,
    Conditions,
    ConditionsError,
    conditions_from_dict,
)
from sdhn_sim.lockstep import LockstepSim, SimConfig, SimConfigError

from .envs_helpers import TINY_ACTOR, Row, greedy_lockstep


def random_obs(rng: np.random.Generator, b: int, n: int) -> np.ndarray:
    """MAIF-shaped observations: coordinates on an 12-cell grid, window values in {0, 1, 2}."""
    o = np.empty((b, n, 57), dtype=np.float32)
    o[:, :, :8] = rng.integers(0, 12, size=(b, n, 8)) / 11.0
    o[:, :, 8:] = rng.integers(0, 3, size=(b, n, 49))
    o[:, :, 8 + 24] = 0.0
    return o


def run(model: ConditionModel, steps: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    b, n = model.num_envs, model.num_robots
    model.start(None, random_obs(rng, b, n))
    out = []
    for _ in range(steps):
        seen = model.observe(random_obs(rng, b, n))
        applied = model.act(rng.integers(0, 5, size=(b, n)))
        out.append((seen, applied))
    return out


# --- validation --------------------------------------------------------------------------------


@pytest.mark.parametrize(("block", "field"), [
    ({"latency": -1}, "latency"), ({"latency": 1.5}, "latency"),
    ({"lost_actions": 1.0}, "lost_actions"), ({"lost_actions": "x"}, "lost_actions"),
    ({"slow_rate": 0}, "slow_rate"), ({"slow_fraction": 1.2}, "slow_fraction"),
    ({"position_noise": float("nan")}, "position_noise"), ({"cell_misread": -0.1}, "cell_misread"),
    ({"failures": 4}, "failures"), ({"failure_horizon": 0}, "failure_horizon"),
    ({"latency_random": 1}, "latency_random"), ({"seed": -2}, "seed"), ({"lag": 1}, "lag"),
    ({"randomise": "yes"}, "randomise"),
])
def test_a_bad_field_is_named_in_one_line(block: dict, field: str) -> None:
    with pytest.raises(ConditionsError) as e:
        conditions_from_dict(block, num_robots=4)
    msg = str(e.value)
    assert msg.startswith(f"conditions.{field}:") and "\n" not in msg and "allowed" in msg


def test_yaml_integers_read_as_probabilities_and_empty_is_ideal() -> None:
    assert conditions_from_dict({"lost_actions": 0, "slow_rate": 1}).ideal
    assert conditions_from_dict(None).ideal and conditions_from_dict({}).ideal
    c = conditions_from_dict({"latency": 2, "latency_random": True})
    assert not c.ideal and c.active() == {"latency": 2, "latency_random": True}
    with pytest.raises(ConditionsError, match=r"conditions\.cell_misread"):
        conditions_from_dict({"cell_misread": 0.1}, maif=False)


def test_simulator_reads_a_conditions_block_from_text() -> None:
    c = SimConfig.parse_conditions("{latency: 1, lost_actions: 0.05}")
    assert c == Conditions(latency=1, lost_actions=0.05)
    assert SimConfig.parse_conditions("").ideal
    with pytest.raises(SimConfigError, match=r"conditions\.latency"):
        SimConfig.parse_conditions("latency: -3")
    with pytest.raises(SimConfigError, match=r"conditions\.failures"):
        SimConfig(env="maif-tiny", conditions=Conditions(failures=4)).validate()


# --- properties --------------------------------------------------------------------------------


def test_ideal_is_the_identity() -> None:
    rng = np.random.default_rng(0)
    m = ConditionModel(Conditions(), 3, 4, seed=5, grid_size=12)
    m.start(None, random_obs(rng, 3, 4))
    for _ in range(20):
        o = random_obs(rng, 3, 4)
        a = rng.integers(0, 5, size=(3, 4))
        assert np.array_equal(m.observe(o), o) and np.array_equal(m.act(a), a)
    assert not m.obs_age.any()


CONDS = st.builds(
    Conditions, latency=st.integers(0, 3), latency_random=st.booleans(),
    lost_actions=st.floats(0, 0.9), slow_fraction=st.floats(0, 1), slow_rate=st.floats(0.1, 1),
    position_noise=st.floats(0, 1), cell_misread=st.floats(0, 1), failures=st.integers(0, 3),
    failure_horizon=st.integers(1, 10))


@settings(max_examples=25, deadline=None)
@given(cond=CONDS, seed=st.integers(0, 1000))
def test_seeded_determinism_and_env_b_is_a_single_env_seeded_s_plus_b(cond: Conditions,
                                                                       seed: int) -> None:
    a = run(ConditionModel(cond, 3, 4, seed=seed, grid_size=12), 12)
    b = run(ConditionModel(cond, 3, 4, seed=seed, grid_size=12), 12)
    for (sa, aa), (sb, ab) in zip(a, b, strict=True):
        assert np.array_equal(sa, sb) and np.array_equal(aa, ab)
    # env 2 of the batch draws what a one-env model seeded seed + 2 draws on the same inputs
    single = ConditionModel(cond, 1, 4, seed=seed + 2, grid_size=12)
    rng = np.random.default_rng(0)
    first = random_obs(rng, 3, 4)
    single.start(None, first[2:3])
    for seen, applied in a:
        o = random_obs(rng, 3, 4)
        s_seen = single.observe(o[2:3])
        s_applied = single.act(rng.integers(0, 5, size=(3, 4))[2:3])
        assert np.array_equal(s_seen[0], seen[2]) and np.array_equal(s_applied[0], applied[2])


@settings(max_examples=25, deadline=None)
@given(cond=CONDS, seed=st.integers(0, 1000))
def test_conditions_only_ever_stop_actions_and_keep_observations_well_formed(
        cond: Conditions, seed: int) -> None:
    rng = np.random.default_rng(seed)
    m = ConditionModel(cond, 2, 4, seed=seed, grid_size=12)
    m.start(None, random_obs(rng, 2, 4))
    for _ in range(15):
        o = random_obs(rng, 2, 4)
        a = rng.integers(0, 5, size=(2, 4))
        seen = m.observe(o)
        applied = m.act(a)
        assert np.all((applied == a) | (applied == 0))
        assert np.all((m.obs_age >= 0) & (m.obs_age <= cond.latency))
        assert set(np.unique(seen[:, :, 8:])) <= {0.0, 1.0, 2.0}
        assert np.all((seen[:, :, :2] >= 0) & (seen[:, :, :2] <= 1))
        assert np.array_equal(seen[:, :, 2:8], seen[:, :, 2:8])  # no NaN
        assert np.array_equal(seen[:, :, 8 + 24], np.zeros((2, 4)))


# --- each condition's effect -------------------------------------------------------------------


def test_fixed_latency_shows_the_observation_k_steps_old_clamped_at_the_start() -> None:
    m = ConditionModel(Conditions(latency=2), 1, 2, seed=0, grid_size=12)
    rng = np.random.default_rng(1)
    hist = [random_obs(rng, 1, 2)]
    m.start(None, hist[0])
    assert np.array_equal(m.observe(hist[0]), hist[0])
    for t in range(1, 8):
        m.act(np.zeros((1, 2), dtype=np.int64))
        hist.append(random_obs(rng, 1, 2))
        seen = m.observe(hist[-1])
        assert np.array_equal(seen, hist[max(0, t - 2)])
        assert np.all(m.obs_age == min(t, 2))


def test_random_latency_draws_every_age_and_each_message_is_one_of_the_recent_ones() -> None:
    m = ConditionModel(Conditions(latency=2, latency_random=True), 1, 8, seed=3, grid_size=12)
    rng = np.random.default_rng(2)
    hist = [random_obs(rng, 1, 8)]
    m.start(None, hist[0])
    m.observe(hist[0])
    ages = []
    for t in range(1, 60):
        m.act(np.zeros((1, 8), dtype=np.int64))
        hist.append(random_obs(rng, 1, 8))
        seen = m.observe(hist[-1])
        for i in range(8):
            assert np.array_equal(seen[0, i], hist[t - int(m.obs_age[0, i])][0, i])
        ages.extend(m.obs_age[0].tolist())
    assert set(ages) == {0, 1, 2}


def test_lost_actions_are_lost_at_about_their_rate() -> None:
    m = ConditionModel(Conditions(lost_actions=0.2), 4, 10, seed=1, grid_size=12)
    m.start(None, np.zeros((4, 10, 57), dtype=np.float32))
    kept = [m.act(np.ones((4, 10), dtype=np.int64)).mean() for _ in range(200)]
    assert abs(1 - np.mean(kept) - 0.2) < 0.02
    assert m.counts["lost_actions"] == round((1 - np.mean(kept)) * 8000)


def test_slow_robots_are_a_fixed_set_per_episode_acting_at_their_rate() -> None:
    m = ConditionModel(Conditions(slow_fraction=0.5, slow_rate=0.25), 2, 10, seed=4,
                       grid_size=12)
    m.start(None, np.zeros((2, 10, 57), dtype=np.float32))
    acted = np.mean([m.act(np.ones((2, 10), dtype=np.int64)) for _ in range(400)], axis=0)
    assert np.array_equal(acted == 1.0, ~m.slow) and m.slow.sum(axis=1).tolist() == [5, 5]
    assert abs(acted[m.slow].mean() - 0.25) < 0.04
    before = m.slow.copy()
    m.start([1], np.zeros((2, 10, 57), dtype=np.float32))
    assert np.array_equal(m.slow[0], before[0])  # env 0 keeps its episode's draws


def test_failed_robots_stop_for_good_at_a_step_within_the_horizon() -> None:
    m = ConditionModel(Conditions(failures=2, failure_horizon=20), 3, 5, seed=9, grid_size=12)
    m.start(None, np.zeros((3, 5, 57), dtype=np.float32))
    out = np.array([m.act(np.ones((3, 5), dtype=np.int64)) for _ in range(40)])  # [T, B, N]
    assert (m.fail_step < 20).sum(axis=1).tolist() == [2, 2, 2]
    for b in range(3):
        for i in range(5):
            f = m.fail_step[b, i]
            if f < 20:
                assert np.all(out[:f, b, i] == 1) and np.all(out[f:, b, i] == 0)
            else:
                assert np.all(out[:, b, i] == 1)
    assert m.failed.sum() == 6 and m.counts["failed_robots"] == 6


def test_position_noise_moves_the_own_cell_by_one_and_misreads_change_cells() -> None:
    m = ConditionModel(Conditions(position_noise=1.0), 1, 50, seed=0, grid_size=12)
    o = random_obs(np.random.default_rng(0), 1, 50)
    o[:, :, :2] = 5 / 11.0
    m.start(None, o)
    seen = m.observe(o)
    step = np.rint((seen[0, :, :2] - o[0, :, :2]) * 11)
    assert np.all(np.abs(step).sum(axis=1) == 1)  # every robot one cell off, 4-neighbour
    assert np.array_equal(seen[:, :, 2:], o[:, :, 2:])
    m2 = ConditionModel(Conditions(cell_misread=0.1), 1, 50, seed=0, grid_size=12)
    m2.start(None, o)
    seen2 = m2.observe(o)
    changed = seen2[0, :, 8:] != o[0, :, 8:]
    assert abs(changed.mean() - 0.1 * 48 / 49) < 0.02 and not changed[:, 24].any()
    assert np.array_equal(seen2[:, :, :8], o[:, :, :8])


def test_a_reset_env_starts_a_fresh_episode_and_leaves_the_others_alone() -> None:
    cond = Conditions(latency=3, lost_actions=0.3, failures=1, failure_horizon=5)
    m = ConditionModel(cond, 2, 4, seed=0, grid_size=12)
    rng = np.random.default_rng(0)
    m.start(None, random_obs(rng, 2, 4))
    for _ in range(6):
        m.observe(random_obs(rng, 2, 4))
        m.act(np.ones((2, 4), dtype=np.int64))
    fresh = random_obs(rng, 2, 4)
    m.start([0], fresh)
    assert m.t.tolist() == [0, 6] and m.episode.tolist() == [1, 0]
    assert not m.failed[0].any() and m.failed[1].any()
    seen = m.observe(fresh)
    assert np.array_equal(seen[0], fresh[0]) and np.all(m.obs_age[1] == 3)
    # the new episode draws as episode 1 of a one-env model seeded 0 does
    one = ConditionModel(cond, 1, 4, seed=0, grid_size=12)
    one.start(None, fresh[:1])
    one.start(None, fresh[:1])
    assert np.array_equal(one.fail_step[0], m.fail_step[0])


# --- the wrapper and the simulator core agree --------------------------------------------------


def play_in_process(cond: Conditions, seed: int, episodes: int,
                    dead_reckoning: bool = False) -> list[tuple]:
    """Greedy maif-tiny episodes under ``cond``, optionally with dead reckoning as
    condition_eval applies it (each robot's observation moved by its actions since)."""
    rt = ActorRuntime.from_file(TINY_ACTOR)
    env = ConditionedEnv(make_env("maif-tiny", num_envs=1, seed=seed, max_steps=60), cond)
    obs, _ = env.reset()
    h = rt.initial_state(4)
    rng = np.random.default_rng(0)
    dr = DeadReckoner(4, 12) if dead_reckoning else None
    out: list[tuple] = []
    while len(out) < episodes:
        seen = dr.correct(obs[0], env.obs_age[0]) if dr is not None else obs[0]
        a, _, h = rt.act(seen, h, greedy=True, rng=rng)
        if dr is not None:
            dr.record(a)
        res = env.step(a[None])
        out += [(o.completed, o.makespan, o.survivors_completed, o.survivors_makespan, o.failed)
                for o in env.outcomes]
        if res.episodes:  # (after a survivors' outcome the env's episode goes on to its end)
            h = rt.initial_state(4)
            if dr is not None:
                dr.reset()
        obs = res.obs
    return out[:episodes]


def play_lockstep(cond: Conditions, seed: int, episodes: int) -> list[Row]:
    sim = LockstepSim(SimConfig(env="maif-tiny", seed=seed, max_steps=60, conditions=cond))
    return greedy_lockstep(sim, episodes)[0]


@pytest.mark.parametrize("cond", [
    Conditions(latency=1, latency_random=True, lost_actions=0.1),
    Conditions(failures=1, failure_horizon=8, latency=1, latency_random=True),
    Conditions(slow_fraction=0.5, slow_rate=0.5, position_noise=0.1, cell_misread=0.05),
    Conditions(latency=2, lost_actions=0.2, slow_fraction=0.5, slow_rate=0.5, failures=1,
               failure_horizon=8, randomise=True),
])
def test_in_process_and_lockstep_give_the_same_outcomes(cond: Conditions) -> None:
    a = play_in_process(cond, seed=7, episodes=4)
    assert a == play_lockstep(cond, seed=7, episodes=4)
    assert any(x[2] for x in a)  # some episodes complete: the comparison is not all NC


def test_rware_runs_under_latency_loss_slowness_and_failure() -> None:
    env = make_env("rware-tiny-2ag", num_envs=2, seed=3, max_steps=40)
    cond = Conditions(latency=1, lost_actions=0.2, slow_fraction=0.5, slow_rate=0.5,
                      failures=1, failure_horizon=10)
    wrapped = ConditionedEnv(env, cond)
    obs, _ = wrapped.reset()
    rng = np.random.default_rng(0)
    outcomes = []
    for _ in range(40):
        a = rng.integers(0, env.num_actions, size=(2, env.num_robots))
        res = wrapped.step(a)
        outcomes += wrapped.outcomes
        assert res.obs.shape == obs.shape
    assert sorted(o.env_index for o in outcomes) == [0, 1]
    assert all(o.deliveries is not None and o.failed == 1 for o in outcomes)
    assert wrapped.model.counts["lost_actions"] > 0 and wrapped.model.counts["stale_obs"] > 0
    with pytest.raises(ConditionsError, match=r"conditions\.position_noise"):
        ConditionedEnv(env, Conditions(position_noise=0.1))


def test_randomise_draws_each_episode_between_the_ideal_and_the_given_severity() -> None:
    cond = Conditions(latency=3, lost_actions=0.2, slow_fraction=0.5, slow_rate=0.4,
                      position_noise=0.1, cell_misread=0.05, failures=2, randomise=True)
    m = ConditionModel(cond, 64, 8, seed=5, grid_size=12)
    obs = random_obs(np.random.default_rng(0), 64, 8)
    drawn: dict[str, list[np.ndarray]] = {k: [] for k in m.severity}
    for _ in range(3):  # three episodes of 64 envs
        m.start(None, obs)
        for k, v in m.severity.items():
            drawn[k].append(v.copy())
        assert np.array_equal(m.slow.sum(axis=1), np.rint(m.severity["slow_fraction"] * 8)
                              * (m.severity["slow_rate"] < 1))
        assert np.array_equal((m.fail_step < np.iinfo(np.int64).max).sum(axis=1),
                              m.severity["failures"])
    sev = {k: np.concatenate(v) for k, v in drawn.items()}
    assert set(sev["latency"].tolist()) == {0, 1, 2, 3}
    assert set(sev["failures"].tolist()) == {0, 1, 2}
    for k, hi in (("lost_actions", 0.2), ("slow_fraction", 0.5), ("position_noise", 0.1),
                  ("cell_misread", 0.05)):
        assert sev[k].min() >= 0 and sev[k].max() < hi and sev[k].std() > hi / 5, k
    assert sev["slow_rate"].min() >= 0.4 and sev["slow_rate"].max() <= 1
    m.observe(obs)
    assert np.array_equal(m.obs_age.max(axis=1), np.zeros(64))  # step 0: nothing is stale yet
    assert "randomise" in cond.active() and cond.label().endswith("randomise=True")


def test_fixed_severities_are_every_episode_the_given_ones() -> None:
    cond = Conditions(latency=2, lost_actions=0.1, slow_fraction=0.5, slow_rate=0.5)
    m = ConditionModel(cond, 4, 8, seed=5, grid_size=12)
    m.start(None, random_obs(np.random.default_rng(0), 4, 8))
    assert m.severity["latency"].tolist() == [2] * 4
    assert m.severity["lost_actions"].tolist() == [0.1] * 4
    assert m.slow.sum(axis=1).tolist() == [4] * 4
