"""RWARE dead reckoning (sdhn_policy.dead_reckoning.RwareDeadReckoner): a stale observation moved
forward by the robot's own sent actions reproduces what the real rware package shows it now,
wherever nothing the robot cannot know changed; and the latency mechanism it removes, measured."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sdhn_experiments.rware_conditions import play_rware, scripted
from sdhn_policy.dead_reckoning import ActionHistory, RwareDeadReckoner
from sdhn_sim.envs.conditions import Conditions
from sdhn_sim.envs.registry import make_env
from sdhn_sim.envs.rware_batched import FORWARD, LEFT, NOOP, RIGHT, TOGGLE, RwareBatchedEnv
from sdhn_sim.envs.rware_env import RwareEnv

SELF = 8  # x, y, loaded, heading one-hot, on highway


def lone_robot(seed: int, max_steps: int = 500) -> RwareEnv:
    """One robot in rware-3's warehouse, the real package: only its own actions change what
    it sees, apart from requests drawn on a delivery."""
    return RwareEnv(1, num_envs=1, seed=seed, max_steps=max_steps)


def layout() -> RwareBatchedEnv:
    env = make_env("rware-3", num_envs=1)
    assert isinstance(env, RwareBatchedEnv)
    return env


def test_a_current_observation_or_unseen_noops_change_nothing() -> None:
    env = layout()
    obs, _ = env.reset(seed=4)
    rows = obs.reshape(3, -1)
    dr = RwareDeadReckoner(3, env.layout)
    assert np.array_equal(dr.correct(rows, [0, 0, 0]), rows)
    assert np.array_equal(dr.correct(rows, [2, 2, 2]), rows)  # nothing sent this episode
    dr.record([NOOP, NOOP, NOOP])
    assert np.array_equal(dr.correct(rows, [1, 1, 1]), rows)
    dr.record([FORWARD, NOOP, NOOP])
    out = dr.correct(rows, [0, 2, 2])  # row 0 current; rows 1, 2 saw only no-ops
    assert np.array_equal(out, rows)


def test_redrawing_the_seen_state_reproduces_rware_bit_for_bit() -> None:
    # the renderer is exact: a robot's own state redrawn on the floor it saw is what rware wrote
    env = make_env("rware-9", num_envs=4, seed=2)
    assert isinstance(env, RwareBatchedEnv)
    obs, _ = env.reset()
    dr = RwareDeadReckoner(4 * 9, env.layout)
    rng = np.random.default_rng(0)
    for _ in range(60):
        rows = obs.reshape(36, -1)
        redrawn = dr._predict(rows, np.zeros(36, dtype=np.int64), np.arange(36))
        assert np.array_equal(redrawn, rows)
        obs = env.step(rng.integers(0, 5, (4, 9))).obs


@pytest.mark.parametrize("delay", [1, 2, 3])
def test_a_lone_robot_moved_forward_sees_what_rware_shows_it_now(delay: int) -> None:
    env = lone_robot(seed=7)
    obs, _ = env.reset()
    hist = [obs[0, 0]]
    dr = RwareDeadReckoner(1, layout().layout)
    rng = np.random.default_rng(delay)
    own_exact = total = 0
    for _ in range(300):
        a = int(rng.choice(5, p=[0.05, 0.5, 0.15, 0.15, 0.15]))
        dr.record([a])
        res = env.step(np.array([[a]]))
        if res.episodes:
            break
        hist.append(res.obs[0, 0])
        if len(hist) <= delay:
            continue
        pred = dr.correct(hist[-1 - delay][None], [delay])[0]
        now = hist[-1]
        total += 1
        own_exact += int(np.array_equal(pred[:SELF], now[:SELF]))
        if delay == 1:
            # one action: its target is in the window it saw, so the robot's own state is exact
            # and every cell it saw before and sees now reads alike
            assert np.array_equal(pred[:SELF], now[:SELF])
    assert total > 200
    # beyond the window the plan stands in for the floor: a shelf this robot moved before
    assert own_exact / total > 0.98


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), actions=st.lists(st.sampled_from(
    [FORWARD, FORWARD, LEFT, RIGHT]), min_size=1, max_size=6))
def test_unloaded_moves_and_turns_predict_the_robots_pose(seed: int, actions: list[int]) -> None:
    # an empty-handed robot is stopped by nothing but the grid's edge (alone): exact pose
    env = lone_robot(seed)
    obs, _ = env.reset()
    first = obs[0, 0]
    dr = RwareDeadReckoner(1, layout().layout)
    for a in actions:
        dr.record([a])
        obs = env.step(np.array([[a]])).obs
    pred = dr.correct(first[None], [len(actions)])[0]
    assert np.array_equal(pred[:SELF], obs[0, 0, :SELF])
    centre = SELF + 4 * 7  # the robot's own window cell shows it with its heading
    assert np.array_equal(pred[centre:centre + 5], obs[0, 0, centre:centre + 5])


def test_a_loaded_robot_is_stopped_by_a_seen_shelf_and_carries_its_own() -> None:
    env = layout()
    lay = env.layout
    dr = RwareDeadReckoner(1, lay)
    # a robot at storage cell (1, 1), under a shelf, facing right (towards (2, 1): a shelf)
    o = np.zeros(dr.obs_size, dtype=np.float32)
    o[0], o[1], o[3 + 3] = 1, 1, 1.0
    cells = o[SELF:].reshape(3, 3, 7)
    for wy in range(3):
        for wx in range(3):
            x, y = wx, wy  # window origin (0, 0)
            cells[wy, wx, 1] = 1.0
            cells[wy, wx, 5] = float(not lay.highway[y, x])
    cells[1, 1, 0:5] = [1, 0, 0, 0, 1]
    dr.record([TOGGLE])  # picks up the shelf under it
    dr.record([FORWARD])  # loaded into a shelf: refused
    pred = dr.correct(o[None], [2])[0]
    assert pred[2] == 1.0 and (pred[0], pred[1]) == (1, 1)
    dr.record([LEFT])  # faces up, towards (1, 0): a highway, no shelf
    dr.record([FORWARD])
    pred = dr.correct(o[None], [4])[0]
    assert (pred[0], pred[1], pred[2]) == (1, 0, 1.0) and pred[3] == 1.0  # up, loaded
    pc = pred[SELF:].reshape(3, 3, 7)
    assert pc[1, 1, 5] == 1.0  # the carried shelf stands with it
    assert pc[2, 1, 5] == 0.0  # and is gone from (1, 1)
    dr.record([TOGGLE])  # on a highway: rware keeps the load
    assert dr.correct(o[None], [5])[0][2] == 1.0


def test_action_history_counts_the_episode_and_forgets_reset_rows() -> None:
    h = ActionHistory(2, horizon=3)
    assert h.unseen([5, 5]).tolist() == [0, 0]
    for a in (1, 2, 3, 4):
        h.record([a, a])
    assert h.unseen([1, 9]).tolist() == [1, 3]  # capped by the horizon
    assert h.sent(1).tolist() == [4, 4] and h.sent(3).tolist() == [2, 2]
    h.reset([1])
    assert h.unseen([2, 2]).tolist() == [2, 0]
    h.record([0, 3])
    assert h.unseen([2, 2]).tolist() == [2, 1] and h.sent(1).tolist() == [0, 3]


def test_latency_turns_the_scripted_robots_past_their_targets_and_the_rule_undoes_it() -> None:
    # the measured mechanism, small: 2 episodes of 150 steps of the scripted policy
    def pol(b: int, n: int):  # type: ignore[no-untyped-def]
        return scripted("rware-3", n)

    def run(lat: int, dr: bool):  # type: ignore[no-untyped-def]
        return play_rware(pol, "rware-3", Conditions(latency=lat), episodes=2, seed=1_000_000,
                          dead_reckon=dr, max_steps=150)

    ideal, stale, reckoned = run(0, False), run(1, False), run(1, True)
    assert ideal.mechanism.rates()["turn_off_target"] == 0.0
    assert stale.mechanism.rates()["turn_off_target"] > 0.3  # measured 0.50 over 10 episodes
    assert stale.mechanism.rates()["forward_off_heading"] > 0.3
    assert reckoned.mechanism.rates()["turn_off_target"] == 0.0
    assert sum(stale.deliveries) == 0 < sum(reckoned.deliveries)


def synthetic(lay_env: RwareBatchedEnv, x: int, y: int, heading: int,
              gaps: tuple[tuple[int, int], ...] = ()) -> np.ndarray:
    """A lone robot's observation at (x, y): shelves where the plan puts them but at ``gaps``."""
    lay = lay_env.layout
    o = np.zeros(SELF + 9 * 7, dtype=np.float32)
    o[0], o[1], o[3 + heading], o[7] = x, y, 1.0, float(lay.highway[y, x])
    cells = o[SELF:].reshape(3, 3, 7)
    for wy in range(3):
        for wx in range(3):
            cx, cy = x + wx - 1, y + wy - 1
            cells[wy, wx, 1] = 1.0
            inside = 0 <= cx < lay.width and 0 <= cy < lay.height
            cells[wy, wx, 5] = float(inside and not lay.highway[cy, cx] and (cx, cy) not in gaps)
    cells[1, 1, 0:5] = 0.0
    cells[1, 1, 0], cells[1, 1, 1 + heading] = 1.0, 1.0
    return o


@pytest.mark.parametrize("memory", [True, False])
def test_a_gap_seen_before_is_remembered_and_forgotten_with_the_episode(memory: bool) -> None:
    env = layout()
    dr = RwareDeadReckoner(1, env.layout, memory=memory)
    up = 0
    gap = (2, 2)  # a storage cell whose shelf is gone
    dr.record([NOOP])
    dr.correct(synthetic(env, 1, 1, up, gaps=(gap,))[None], [0])  # seen, current
    # an older observation arriving after it (random latency) does not overwrite it
    dr.correct(synthetic(env, 1, 1, up)[None], [1])
    # later: the robot at (1, 4) facing up, two forward moves unseen: it stands at (1, 2)
    later = synthetic(env, 1, 4, up)
    dr.record([FORWARD])
    dr.record([FORWARD])
    pred = dr.correct(later[None], [2])[0]
    assert (pred[0], pred[1]) == (1, 2)
    shown = pred[SELF:].reshape(3, 3, 7)[1, 2, 5]  # the window cell of (2, 2)
    assert shown == (0.0 if memory else 1.0)
    dr.reset()  # a new episode: the plan again
    dr.record([FORWARD])
    dr.record([FORWARD])
    assert dr.correct(later[None], [2])[0][SELF:].reshape(3, 3, 7)[1, 2, 5] == 1.0
