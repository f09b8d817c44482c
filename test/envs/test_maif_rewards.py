"""The two named MAIF rewards: ``reference`` (the benchmark's terms, with its two traps) and
``corrected`` (the default: progress +0.1 closer / -0.1 farther, no stay-on-goal income).

Each trap is pinned both ways: it pays under ``reference`` and does not under ``corrected``.
"""

from __future__ import annotations

import numpy as np
import pytest

from sdhn_sim.envs import MAIF_REWARDS, make_env, make_single_env

from .envs_helpers import scenario

STAY, UP, DOWN, LEFT, RIGHT = range(5)


def episode_return(env, actions_per_step) -> tuple[float, bool]:
    """Sum of team rewards until the episode ends; (return, completed)."""
    total = 0.0
    for actions in actions_per_step:
        res = env.step(np.array([actions]))
        total += float(res.reward[0])
        if res.terminated[0] or res.truncated[0]:
            return total, bool(res.terminated[0])
    raise AssertionError("the episode did not end")


def oscillate_vs_stay(reward: str, steps: int = 40) -> tuple[float, float]:
    """One robot far from its goal: step left/right forever vs stay forever."""
    def env():
        return scenario([(3, 1)], [(6, 6)], reward=reward, max_steps=steps)
    osc, _ = episode_return(env(), [[LEFT if t % 2 == 0 else RIGHT] for t in range(steps)])
    stay, _ = episode_return(env(), [[STAY]] * steps)
    return osc, stay


def test_oscillating_pays_under_reference():
    osc, stay = oscillate_vs_stay("reference")
    # -0.025 per step against -0.075 (+0.0005 formation term, one robot is always in formation):
    # the trap the corrected reward removes
    assert osc == pytest.approx(-0.0245 * 40, abs=1e-4)
    assert stay == pytest.approx(-0.0745 * 40, abs=1e-4)
    assert osc > stay + 1.0


def test_oscillating_never_beats_staying_under_corrected():
    osc, stay = oscillate_vs_stay("corrected")
    assert osc <= stay + 1e-6, (osc, stay)
    # and walking towards the goal beats both
    walk, done = episode_return(
        scenario([(3, 1)], [(6, 6)], reward="corrected", max_steps=40),
        [[RIGHT]] * 3 + [[DOWN]] * 5)
    assert done and walk > stay


def complete_vs_all_but_one(reward: str, limit: int = 60) -> tuple[float, float]:
    """Three robots one step from their goals: all step on (complete at once) vs all but the
    last (who then waits beside its goal until the step limit)."""
    starts, goals = [(1, 1), (3, 3), (5, 5)], [(1, 2), (3, 4), (5, 6)]

    def env():
        return scenario(starts, goals, reward=reward, max_steps=limit)
    complete, ok = episode_return(env(), [[DOWN, DOWN, DOWN]])
    assert ok
    partial, ok2 = episode_return(env(), [[DOWN, DOWN, STAY]] + [[STAY] * 3] * limit)
    assert not ok2
    return complete, partial


def test_completing_loses_under_reference():
    complete, partial = complete_vs_all_but_one("reference")
    assert partial > 10 * complete > 0


def test_completing_wins_under_corrected():
    complete, partial = complete_vs_all_but_one("corrected")
    assert complete > 0 > partial
    # no stay-on-goal income above what completing is worth per robot-step (spec bound)
    rw = MAIF_REWARDS["corrected"]
    assert rw.stay_on_goal <= rw.completion * (1 - 0.99) / 3


def test_corrected_is_the_default_and_reward_is_an_override():
    assert make_env("maif-tiny").reward_name == "corrected"
    assert make_env("maif-tiny", reward="reference").reward_name == "reference"
    assert make_single_env("maif-tiny", reward="reference").env.reward_name == "reference"
    with pytest.raises(ValueError, match="reward"):
        make_env("maif-tiny", reward="shaped")
    with pytest.raises(ValueError, match="reward"):
        make_env("rware-3", reward="corrected")
