"""The evaluation's per-set metrics: RWARE's deliveries beside the return, MAIF without them."""

from __future__ import annotations

import pytest

from sdhn_sim.envs import make_env
from sdhn_sim.envs.rware_env import RwareEnv
from sdhn_sim.envs.rware_scripted import ScriptedPolicy, run_episodes
from sdhn_train.evaluation import headline, set_metrics


@pytest.mark.filterwarnings("ignore:.*reward returned by")
def test_rware_evaluation_logs_deliveries():
    env = make_env("rware-3", num_envs=2, seed=0, max_steps=100, backend="rware")
    assert isinstance(env, RwareEnv)
    eps = run_episodes(env, ScriptedPolicy(seed=0), seed=0)
    m = set_metrics("", eps)
    expected = sum(e.deliveries or 0 for e in eps) / 2
    assert m["eval/deliveries"] == expected > 0, (m, eps)
    assert m["eval/success_rate"] == 0.0
    assert f"deliveries {expected:.1f}" in headline(m), headline(m)


def test_maif_evaluation_has_no_deliveries():
    env = make_env("maif-tiny", num_envs=2, seed=0, max_steps=5)
    env.reset(seed=0)
    eps = []
    while len(eps) < 2:
        eps += env.step([[0] * env.num_robots] * 2).episodes
    m = set_metrics("heldout_", eps)
    assert "eval/heldout_episodic_return" in m
    assert not any("deliveries" in k for k in m), m
