"""``train.conditions``: the in-process trainer learns under deployment conditions (fixed, or
randomised per episode), evaluates in the ideal world, resumes exactly, and refuses a bad block
in one line naming the field."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sdhn_sim.envs import make_env
from sdhn_sim.envs.api import BatchedEnv
from sdhn_train.config import Config, ConfigError, set_field, validate
from sdhn_train.env_features import conditioned
from sdhn_train.rollout import Rollout
from sdhn_train.trainer import Trainer


def short_episodes(name: str, num_envs: int, seed: int, **kw: Any) -> BatchedEnv:
    """12-step episodes, so a rollout crosses episode ends (a new episode's severities)."""
    return make_env(name, num_envs=num_envs, seed=seed, max_steps=12)


def _cfg(conditions: Any, seed: int = 3, root: Path | None = None) -> Config:
    cfg = Config()
    cfg.env.name, cfg.env.num_envs = "maif-tiny", 4
    cfg.env.features = "identity"  # the rollout holds raw observations and the world's state
    cfg.algo.name = "mappo"
    cfg.ppo.rollout_len, cfg.ppo.num_minibatches, cfg.ppo.epochs = 16, 2, 1
    cfg.train.seed, cfg.train.total_steps = seed, 10_000
    cfg.eval.interval, cfg.log.tensorboard, cfg.log.progress = 0, False, False
    cfg.log.root = str(root or "runs")
    set_field(cfg, "train.conditions", conditions)
    validate(cfg)
    return cfg


def _seen_vs_world(r: Rollout) -> tuple[np.ndarray, np.ndarray]:
    """(what the robots saw, the world's observations) per step: [T, B, N, D] each."""
    t, b, n, d = r.obs.shape
    return r.obs, r.state.reshape(t, b, n, d)


def test_the_rollout_holds_what_the_robots_saw_one_step_late(tmp_path: Path) -> None:
    tr = Trainer(_cfg("{latency: 1}"), short_episodes, run_dir=tmp_path / "run")
    r, _ = tr.collector.collect(tr.critic_h)
    seen, world = _seen_vs_world(r)
    ended = r.terminated | r.truncated
    late = 0
    for t in range(1, len(seen)):
        for e in range(seen.shape[1]):
            if ended[t - 1, e]:  # a new episode starts with its own first observation
                np.testing.assert_array_equal(seen[t, e], world[t, e])
            else:
                np.testing.assert_array_equal(seen[t, e], world[t - 1, e])
                late += int(not np.array_equal(seen[t, e], world[t, e]))
    assert late > 0, "the robots moved: a one-step-old observation differs from the world's"
    assert ended[:-1].any(), "the test must cross an episode end"
    assert conditioned(tr.env) is not None


def test_evaluation_stays_in_the_ideal_world(tmp_path: Path) -> None:
    cfg = _cfg({"latency": 2, "lost_actions": 0.5})
    cfg.eval.interval, cfg.eval.instances = 1, 2
    tr = Trainer(cfg, run_dir=tmp_path / "run")
    assert conditioned(tr.env) is not None
    assert tr.eval_envs and all(conditioned(e) is None for e in tr.eval_envs.values())


def test_randomised_severities_vary_per_episode_and_seeds_reproduce(tmp_path: Path) -> None:
    block = {"latency": 2, "lost_actions": 0.3, "slow_fraction": 0.5, "slow_rate": 0.5,
             "randomise": True}

    def rollouts(seed: int) -> tuple[list[Rollout], dict[str, list[np.ndarray]]]:
        tr = Trainer(_cfg(block, seed), short_episodes, run_dir=tmp_path / f"s{seed}")
        env = conditioned(tr.env)
        assert env is not None
        out, sev = [], {k: [] for k in env.model.severity}
        for _ in range(3):
            out.append(tr.collector.collect(tr.critic_h)[0])
            for k, v in env.model.severity.items():
                sev[k].append(v.copy())
        return out, sev

    a, sev = rollouts(3)
    lat = np.concatenate(sev["latency"])
    assert set(lat.tolist()) == {0, 1, 2}, "latency drawn in 0..2 across episodes and envs"
    lost = np.concatenate(sev["lost_actions"])
    assert lost.min() >= 0 and lost.max() < 0.3 and len(set(lost.tolist())) > 4
    rate = np.concatenate(sev["slow_rate"])
    assert rate.min() >= 0.5 and rate.max() <= 1
    b, _ = rollouts(3)
    c, _ = rollouts(4)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.obs, y.obs)
        np.testing.assert_array_equal(x.actions, y.actions)
    assert not all(np.array_equal(x.obs, z.obs) for x, z in zip(a, c, strict=True))


def test_a_resumed_run_draws_and_delays_as_the_uninterrupted_one(tmp_path: Path) -> None:
    block = {"latency": 2, "latency_random": True, "lost_actions": 0.2, "randomise": True}
    a = Trainer(_cfg(block, root=tmp_path), short_episodes, run_dir=tmp_path / "a")
    a.run_dir.mkdir(parents=True)
    a.train_iteration()
    path = a.save_checkpoint()
    a.train_iteration()
    want, _ = a.collector.collect(a.critic_h)
    b = Trainer(_cfg(block, root=tmp_path), short_episodes, run_dir=tmp_path / "b")
    b.load_checkpoint(path)
    b.train_iteration()
    got, _ = b.collector.collect(b.critic_h)
    for name in ("obs", "state", "actions", "rewards", "truncated"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)


@pytest.mark.parametrize(("value", "field"), [
    ("{latency: -1}", "train.conditions.latency"),
    ({"lost_actions": 1.5}, "train.conditions.lost_actions"),
    ({"lag": 1}, "train.conditions.lag"),
    ({"randomise": "sometimes"}, "train.conditions.randomise"),
    ("[1, 2]", "train.conditions"),
    ("{latency: [", "train.conditions"),
])
def test_a_bad_block_is_refused_in_one_line_naming_the_field(value: Any, field: str) -> None:
    cfg = Config()
    with pytest.raises(ConfigError) as e:
        set_field(cfg, "train.conditions", value)
        validate(cfg)
    msg = str(e.value)
    assert msg.startswith(field) and "\n" not in msg and "allowed" in msg, msg


def test_maif_only_conditions_are_refused_for_rware() -> None:
    cfg = Config()
    cfg.env.name = "rware-tiny-2ag"
    set_field(cfg, "train.conditions", {"cell_misread": 0.1})
    with pytest.raises(ConfigError, match=r"^train\.conditions\.cell_misread: .*allowed"):
        validate(cfg)


def test_a_suite_sets_conditions_and_is_validated_before_it_runs(tmp_path: Path) -> None:
    from sdhn_experiments.experiments import load_suite

    def suite(block: str) -> Path:
        p = tmp_path / "suite.yaml"
        p.write_text("name: dr\nmethods:\n  sdhn: {algo: sdhn}\n"
                     f"  sdhn_dr: {{algo: sdhn, set: {{train.conditions: {block}}}}}\n"
                     "tasks: {maif-tiny: {}}\nexperiments: [{methods: [sdhn, sdhn_dr], "
                     "tasks: [maif-tiny]}]\nseeds: [1]\nbudgets: {b: {}}\n")
        return p

    runs = load_suite(suite("{latency: 1, randomise: true}"), "b")
    cfgs = {r.method: r.config(tmp_path / "logs") for r in runs}
    assert cfgs["sdhn_dr"].train.conditions == {"latency": 1, "randomise": True}
    assert cfgs["sdhn"].train.conditions == {}
    with pytest.raises(Exception, match=r"train\.conditions\.slow_rate"):
        load_suite(suite("{slow_rate: 0}"), "b")
