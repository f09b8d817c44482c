"""MAIF transition, conflict, reward and observation rules on hand-built scenarios.

Cells are (x, y), x = column to the right, y = row downwards. Actions: 0 stay, 1 up (y-1),
2 down (y+1), 3 left (x-1), 4 right (x+1).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from .envs_helpers import scenario

STAY, UP, DOWN, LEFT, RIGHT = range(5)
FAR = [(7, 7), (6, 7), (7, 6), (6, 6), (5, 7)]  # goals out of the way


def step(env, actions):
    res = env.step(np.array([actions]))
    return res, env.positions[0].tolist(), env.robot_collisions[0].tolist()


def test_axis_convention():
    env = scenario([(3, 3), (5, 5), (1, 1), (6, 2)], FAR[:4])
    _, pos, coll = step(env, [UP, DOWN, LEFT, RIGHT])
    assert pos == [[3, 2], [5, 6], [0, 1], [7, 2]], pos
    assert coll == [False] * 4


@pytest.mark.parametrize(
    ("start", "action", "obstacles"),
    [((0, 0), UP, []), ((0, 0), LEFT, []), ((7, 7), DOWN, []), ((7, 3), RIGHT, []),
     ((2, 2), RIGHT, [(3, 2)]), ((2, 2), UP, [(2, 1)])],
)
def test_out_of_grid_or_obstacle_stays_and_collides(start, action, obstacles):
    env = scenario([start, (5, 5)], FAR[:2], obstacles=obstacles)
    _, pos, coll = step(env, [action, STAY])
    assert pos[0] == list(start), f"robot moved to {pos[0]}"
    assert coll == [True, False]


@pytest.mark.parametrize("low_on_left", [True, False])
def test_vertex_conflict_lowest_index_wins(low_on_left):
    # two robots head for (2, 2); the one with index 0 gets it whichever side it comes from
    a, b = ((1, 2), RIGHT), ((3, 2), LEFT)
    first, second = (a, b) if low_on_left else (b, a)
    env = scenario([first[0], second[0]], FAR[:2])
    _, pos, coll = step(env, [first[1], second[1]])
    assert pos == [[2, 2], list(second[0])], pos
    assert coll == [False, True]


def test_vertex_conflict_three_way_and_higher_index_wins_nothing():
    env = scenario([(3, 2), (2, 1), (1, 2), (2, 3)], FAR[:4])
    _, pos, coll = step(env, [LEFT, DOWN, RIGHT, UP])  # all four into (2, 2)
    assert pos == [[2, 2], [2, 1], [1, 2], [2, 3]], pos
    assert coll == [False, True, True, True]


def test_staying_robot_keeps_its_cell_even_against_lower_index():
    env = scenario([(1, 2), (2, 2)], FAR[:2])
    _, pos, coll = step(env, [RIGHT, STAY])
    assert pos == [[1, 2], [2, 2]]
    assert coll == [True, False]


def test_swap_both_stay_and_collide():
    env = scenario([(1, 1), (2, 1), (5, 5)], FAR[:3])
    _, pos, coll = step(env, [RIGHT, LEFT, STAY])
    assert pos == [[1, 1], [2, 1], [5, 5]]
    assert coll == [True, True, False]


def test_following_a_moving_robot_is_allowed():
    env = scenario([(1, 1), (2, 1), (3, 1)], FAR[:3])
    _, pos, coll = step(env, [RIGHT, RIGHT, RIGHT])
    assert pos == [[2, 1], [3, 1], [4, 1]]
    assert coll == [False] * 3


def test_blocked_chain_propagates_over_rounds():
    # robot 2 hits an obstacle, so 1 cannot enter its cell, so 0 cannot enter 1's
    env = scenario([(1, 1), (2, 1), (3, 1)], FAR[:3], obstacles=[(4, 1)])
    _, pos, coll = step(env, [RIGHT, RIGHT, RIGHT])
    assert pos == [[1, 1], [2, 1], [3, 1]]
    assert coll == [True, True, True]


def test_chain_blocked_by_lost_vertex_conflict():
    # 0 wins (3,1) against 2; 1 follows 2 into 2's cell but 2 lost, so 1 stops too
    env = scenario([(3, 0), (1, 1), (2, 1)], FAR[:3])
    _, pos, coll = step(env, [DOWN, RIGHT, RIGHT])
    assert pos == [[3, 1], [1, 1], [2, 1]], pos
    assert coll == [False, True, True]


def test_rotation_of_four_moves():
    # a 2x2 cycle has no vertex conflict and no two-robot swap: everyone moves
    env = scenario([(1, 1), (2, 1), (2, 2), (1, 2)], FAR[:4])
    _, pos, coll = step(env, [RIGHT, DOWN, LEFT, UP])
    assert pos == [[2, 1], [2, 2], [1, 2], [1, 1]]
    assert coll == [False] * 4


def formation_term(pos, goals):
    pos, goals = np.asarray(pos, float), np.asarray(goals, float)
    d = np.abs((pos - pos.mean(0)) - (goals - goals.mean(0))).sum(1)
    return (np.exp(-d) - 0.5) * 0.001


@pytest.mark.parametrize(("reward", "on_goal", "away"), [("reference", 1.0, 0.0),
                                                         ("corrected", 0.0, -0.1)])
def test_each_reward_term(reward, on_goal, away):
    # robot 0: moves closer to its goal (move + progress)
    # robot 1: stays off goal; robot 2: stays on goal (reference +1, corrected 0)
    # robot 3: moves into an obstacle (move + collision, no progress)
    # robot 4: moves away from its goal (move; corrected also -0.1)
    starts = [(1, 1), (5, 1), (6, 6), (3, 4), (0, 7)]
    goals = [(3, 1), (5, 3), (6, 6), (3, 6), (0, 6)]
    env = scenario(starts, goals, obstacles=[(3, 5)], reward=reward)
    assert env.reward_name == reward
    res, pos, coll = step(env, [RIGHT, STAY, STAY, DOWN, RIGHT])
    assert pos == [[2, 1], [5, 1], [6, 6], [3, 4], [1, 7]]
    assert coll == [False, False, False, True, False]
    base = np.array([-0.075 + 0.1, -0.075, on_goal, -0.075 - 0.5, -0.075 + away])
    want = base + formation_term(pos, goals)
    np.testing.assert_allclose(env.robot_rewards[0], want, rtol=0, atol=1e-6)
    assert math.isclose(float(res.reward[0]), want.sum(), abs_tol=1e-5)
    assert not res.terminated[0] and not res.truncated[0]


def test_all_on_goal_bonus_and_episode_stats():
    starts = [(1, 1), (2, 2), (4, 4)]
    goals = [(1, 2), (2, 2), (4, 3)]
    env = scenario(starts, goals, reward="reference")
    res = env.step(np.array([[DOWN, STAY, UP]]))
    assert res.terminated[0] and not res.truncated[0]
    want = np.array([-0.075 + 0.1, 1.0, -0.075 + 0.1]) + 3.0 + formation_term(goals, goals)
    np.testing.assert_allclose(env.final_worlds[0].positions, goals)
    np.testing.assert_allclose(res.reward[0], want.sum(), atol=1e-5)
    (ep,) = res.episodes
    assert (ep.makespan, ep.completed, ep.length, ep.collisions) == (1, True, 1, 0)
    assert abs(ep.formation_error) < 1e-9
    # the next episode started: the env is back at the starts
    assert env.positions[0].tolist() == [list(s) for s in starts]


def test_truncation_reports_not_completed():
    env = scenario([(1, 1), (5, 5)], [(6, 6), (7, 7)], max_steps=3)
    for t in range(3):
        res = env.step(np.array([[STAY, LEFT]]))
        assert res.truncated[0] == (t == 2) and not res.terminated[0]
    (ep,) = res.episodes
    assert ep.makespan is None and not ep.completed and ep.length == 3
    assert ep.collisions == 0
    np.testing.assert_array_equal(res.final_obs[0, 1, :2] * 7, [2, 5])  # x moved 5 -> 2


def window(obs_row):
    return obs_row[8:].reshape(7, 7)  # [dy + 3, dx + 3]


def test_observation_window_outside_obstacles_and_every_robot():
    # robot 2 (highest index) must see robots 0 and 1 — the fixed bug hid lower indices
    starts = [(1, 0), (0, 2), (1, 1), (4, 4)]
    env = scenario(starts, FAR[:4], obstacles=[(2, 2), (4, 1)])
    obs, _ = env.reset()
    w = window(obs[0, 2])  # robot 2 at (1, 1)
    expect = np.zeros((7, 7))
    expect[:2, :] = 1  # rows y = -2, -1: outside
    expect[:, :2] = 1  # cols x = -2, -1: outside
    expect[3 + 1, 3 + 1] = 1  # obstacle (2, 2)
    expect[3 + 0, 3 + 3] = 1  # obstacle (4, 1)
    expect[3 - 1, 3 + 0] = 2  # robot 0 at (1, 0)
    expect[3 + 1, 3 - 1] = 2  # robot 1 at (0, 2)
    expect[3 + 3, 3 + 3] = 2  # robot 3 at (4, 4)
    np.testing.assert_array_equal(w, expect)
    # robot 0 sees robots 1 and 2, both of higher index, and itself as free
    w0 = window(obs[0, 0])
    assert w0[3, 3] == 0 and w0[3 + 1, 3 + 0] == 2 and w0[3 + 2, 3 - 1] == 2


def test_observation_coordinates():
    starts, goals = [(0, 0), (7, 1)], [(7, 7), (3, 5)]
    env = scenario(starts, goals)
    obs, state = env.reset()
    want = np.array([[0, 0, 3.5, 0.5, 7, 7, 5, 6], [7, 1, 3.5, 0.5, 3, 5, 5, 6]]) / 7
    np.testing.assert_allclose(obs[0, :, :8], want, atol=1e-6)
    assert obs.dtype == np.float32 and obs.shape == (1, 2, 57)
    np.testing.assert_array_equal(state[0], obs[0].reshape(-1))


@pytest.mark.parametrize("bad", [[[5, 0]], [[-1, 0]], [[0]], [[0.5, 1]]])
def test_bad_actions_raise(bad):
    env = scenario([(1, 1), (3, 3)], FAR[:2])
    with pytest.raises(ValueError, match="actions"):
        env.step(np.array(bad))
