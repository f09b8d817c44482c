"""The environments through PettingZoo's parallel API and Gymnasium, checked by their own tests."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import parallel_api_test, parallel_seed_test

from sdhn_sim.envs.pettingzoo_env import gym_id, parallel_env, register_gymnasium_envs
from sdhn_sim.envs.registry import make_single_env

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", ["maif-tiny", "maif-10", "rware-3"])
def test_passes_pettingzoo_parallel_api_test(name: str) -> None:
    parallel_api_test(parallel_env(name, seed=0, max_steps=40), num_cycles=100)


def test_passes_pettingzoo_seed_test() -> None:
    parallel_seed_test(lambda: parallel_env("maif-tiny", max_steps=30))


def test_robots_observe_their_own_rows_and_rewards_add_up_to_the_team_reward() -> None:
    env = parallel_env("maif-tiny", seed=4)
    twin = make_single_env("maif-tiny", seed=4)
    obs, _ = env.reset(seed=7)
    team_obs, state = twin.reset(seed=7)
    for i, agent in enumerate(env.possible_agents):
        np.testing.assert_array_equal(obs[agent], team_obs[i])
    np.testing.assert_array_equal(env.state(), state)
    rng = np.random.default_rng(0)
    for _ in range(30):
        joint = rng.integers(0, 5, size=4)
        obs, rewards, *_ = env.step({a: joint[i] for i, a in enumerate(env.possible_agents)})
        res = twin.step(joint)
        assert sum(rewards.values()) == pytest.approx(res.reward, abs=1e-5)
        np.testing.assert_array_equal(obs["robot_2"], res.obs[2])


def test_episode_end_removes_every_agent_and_reports_the_episode() -> None:
    env = parallel_env("maif-tiny", seed=0, max_steps=5)
    env.reset(seed=0)
    for step in range(5):
        _, _, term, trunc, infos = env.step({a: 0 for a in env.agents})
        assert (step == 4) == (not env.agents)
    assert all(trunc.values()) and not any(term.values())
    assert infos["robot_0"]["episode"]["length"] == 5
    with pytest.raises(RuntimeError, match="call reset"):
        env.step({})


def test_missing_action_is_one_clear_error() -> None:
    env = parallel_env("maif-tiny")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="missing for"):
        env.step({"robot_0": 1})


BAD_ACTIONS = {  # issue 54 item 8: truncated, taken as 1, or raw Python errors
    "float": 2.7, "whole float": 2.0, "string": "1", "bool": True, "numpy bool": np.bool_(True),
    "nan": float("nan"), "none": None, "negative": -1, "too large": 5, "huge": 2**70,
    "list": [1], "numpy float": np.float32(1.0),
}


@pytest.mark.parametrize("case", list(BAD_ACTIONS))
def test_an_invalid_action_is_one_clear_error_naming_the_agent(case: str) -> None:
    env = parallel_env("maif-tiny")
    env.reset(seed=0)
    actions: dict[str, Any] = {a: 0 for a in env.agents}
    actions["robot_2"] = BAD_ACTIONS[case]
    with pytest.raises(ValueError, match=r"actions\['robot_2'\].*allowed"):
        env.step(actions)
    assert env.agents, "a refused step must not end the episode"
    env.step({a: np.int64(1) for a in env.agents})  # NumPy integers are actions


def test_extra_agents_are_refused_and_unknown_reset_options_warned() -> None:
    env = parallel_env("maif-tiny")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="unknown agents"):
        env.step({**{a: 0 for a in env.agents}, "robot_9": 0})
    with pytest.warns(UserWarning, match="difficulty"):  # PettingZoo's API test passes options
        env.reset(seed=0, options={"difficulty": 3})
    env.reset(seed=0, options={})  # empty is no option


@pytest.mark.parametrize("action", [[0, 1, 2], [0, 1, 2, 3, 4], np.zeros((2, 2), int),
                                    [0.5, 1, 2, 3], [None, 1, 2, 3], 3, np.full(4, np.nan)])
def test_a_joint_action_of_the_wrong_shape_or_type_is_one_clear_error(action: Any) -> None:
    register_gymnasium_envs()
    env = gymnasium.make(gym_id("maif-tiny")).unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match="allowed"):
        env.step(action)
    env.step(np.array([0, 1, 2, 3]))


def test_gymnasium_ids_make_a_checked_joint_env() -> None:
    ids = register_gymnasium_envs()
    assert gym_id("maif-10") in ids and gym_id("rware-3") in ids
    assert register_gymnasium_envs() == ids  # idempotent
    env = gymnasium.make(gym_id("maif-tiny"), max_steps=20)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=1)
    assert obs.shape == (4, 57) and "state" in info
    _, reward, _, _, info = env.step(env.action_space.sample())
    assert info["robot_rewards"].sum() == pytest.approx(reward, abs=1e-5)


def test_example_trains_through_pettingzoo_only(tmp_path: Path) -> None:
    """The example's loop runs end to end and changes its policy (few iterations)."""
    out = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "example_pettingzoo_ppo.py"), "--env",
         "maif-solo", "--iterations", "3", "--steps", "256", "--csv", str(tmp_path / "log.csv")],
        capture_output=True, text=True, timeout=300, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    rows = (tmp_path / "log.csv").read_text().splitlines()
    assert rows[0].startswith("iteration,") and len(rows) == 4, rows
    changes = [float(r.split(",")[-1]) for r in rows[1:]]
    assert all(c > 0 for c in changes), f"the policy's parameters did not move: {changes}"
    assert "import sdhn_train" not in (ROOT / "scripts" / "example_pettingzoo_ppo.py").read_text()


def play_planner(name: str, max_steps: int) -> tuple[dict[str, Any], Any]:
    """One episode driven by the centralised planner (completes MAIF instances), through the
    PettingZoo API; returns the last step's infos and the twin SingleEnv's EpisodeStats."""
    from sdhn_sim.envs.maif_scripted import PlannerPolicy

    env = parallel_env(name, seed=2, max_steps=max_steps)
    twin = make_single_env(name, seed=2, max_steps=max_steps)
    env.reset(seed=3)
    twin.reset(seed=3)
    planner, infos, res = PlannerPolicy(seed=0), {}, None
    while env.agents:
        joint = planner.act(env.env.env)[0]
        _o, _r, _t, _tr, infos = env.step({a: int(joint[i])
                                           for i, a in enumerate(env.possible_agents)})
        res = twin.step(joint)
    assert res is not None
    return infos["robot_0"]["episode"], res.info["episode"]


@pytest.mark.parametrize(("max_steps", "completed"), [(200, True), (3, False)])
def test_episode_metrics_are_numbers_with_documented_sentinels(max_steps: int,
                                                               completed: bool) -> None:
    """TorchRL and BenchMARL keep numeric info leaves only: no None, ever; the project's own
    EpisodeStats comes back from them unchanged."""
    from sdhn_sim.envs.pettingzoo_env import NOT_APPLICABLE, NOT_COMPLETED, episode_from_info

    info, stats = play_planner("maif-tiny", max_steps)
    assert all(isinstance(v, int | float) and not isinstance(v, bool) for v in info.values()), info
    assert info["completed"] == int(completed) and stats.completed == completed, (info, stats)
    if completed:
        assert info["makespan"] == stats.makespan and info["makespan"] > 0, info
    else:
        assert info["makespan"] == NOT_COMPLETED and stats.makespan is None, info
    assert info["deliveries"] == NOT_APPLICABLE
    assert episode_from_info(info) == stats


def test_flat_infos_hold_the_same_numeric_keys_at_every_step() -> None:
    """TorchRL keeps the keys of reset()'s infos only: with flat_infos they are all there from
    the start, numbers, and on the last step they are the episode's metrics."""
    from sdhn_sim.envs.pettingzoo_env import episode_info

    env = parallel_env("maif-tiny", seed=0, max_steps=4, flat_infos=True)
    twin = make_single_env("maif-tiny", seed=0, max_steps=4)
    _, infos = env.reset(seed=1)
    twin.reset(seed=1)
    keys = set(infos["robot_0"])
    assert "episode" not in keys and {"episode_done", "episode_makespan"} <= keys, keys
    while env.agents:
        _o, _r, _t, _tr, infos = env.step({a: 0 for a in env.agents})
        res = twin.step(np.zeros(4, dtype=np.int64))
        for info in infos.values():
            assert set(info) == keys and all(isinstance(v, int | float) for v in info.values())
    last = infos["robot_3"]
    assert last["episode_done"] == 1
    want = episode_info(res.info["episode"])
    assert {k: last[f"episode_{k}"] for k in want if k != "env_index"} == {
        k: v for k, v in want.items() if k != "env_index"}
