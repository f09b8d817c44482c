"""Learning smoke tests of the baselines on maif-tiny (one seed each, CI minutes on one core).

Reference points (16 fixed evaluation instances, 100-step episodes): a uniformly random policy
returns -47.3; the do-nothing policy (every robot stays) -29.8; the untrained greedy policies
-57..-225 (they walk into walls); the PPO algorithms' test reaches -10..-25 in 64k steps.

Measured on 2 shared, heavily loaded cores (load 6-9), greedy return after SETTINGS' steps:
- dicg, 65,536 steps: seed 1 -10.6 (+36.7 over random), ~110 s under load;
- qmix, 40,960 steps: seeds 1/2/3 -32.9 / -20.6 / -29.5 (+14.4 / +26.7 / +17.8), 60-160 s;
- hgcn_mix, 40,960 steps: seed 1 -17.3 (+30.0), 270 s at load 9-18.
At this budget the value-mixing methods mostly learn to stop colliding (about the do-nothing
level) and only sometimes beat it, so their margin (10) is below the do-nothing policy's: the
test shows they learn (from -57..-225 to above random), not that they coordinate. DICG's margin
(20) lies above the do-nothing policy.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from sdhn_sim.envs import make_env
from sdhn_train.config import Config, set_field
from sdhn_train.trainer import Trainer

MAX_STEPS = 100
RETURN_MARGIN = {"qmix": 10.0, "hgcn_mix": 10.0, "dicg": 20.0}  # over random (-47.3)

SETTINGS: dict[str, tuple[int, dict[str, object]]] = {  # algo -> (team steps, overrides)
    # Off-policy: epsilon anneals over the first half; 4 gradient steps of 32 episodes per
    # 1024-step rollout.
    "qmix": (40_960, {"qmix.epsilon_anneal_steps": 20_000, "qmix.updates_per_rollout": 4,
                      "qmix.target_update_interval": 50}),
    "hgcn_mix": (40_960, {"qmix.epsilon_anneal_steps": 20_000, "qmix.updates_per_rollout": 4,
                          "qmix.target_update_interval": 50}),
    # PPO with the DICG critic: the PPO algorithms' test settings.
    "dicg": (65_536, {}),
}


def _cfg(algo: str, seed: int, root: Path) -> Config:
    steps, overrides = SETTINGS[algo]
    cfg = Config()
    cfg.env.name, cfg.env.num_envs, cfg.env.max_steps = "maif-tiny", 16, MAX_STEPS
    cfg.algo.name = algo
    cfg.ppo.rollout_len, cfg.ppo.num_minibatches, cfg.ppo.reward_scale = 64, 2, 0.1
    cfg.train.seed, cfg.train.total_steps = seed, steps
    cfg.eval.interval, cfg.eval.episodes = 0, 16
    # the reference points above were measured with these (issue 13 changed the defaults)
    cfg.env.reward, cfg.env.features = "reference", "identity"
    cfg.log.tensorboard, cfg.log.progress, cfg.log.root = False, False, str(root)
    for key, value in overrides.items():
        set_field(cfg, key, value)
    return cfg


def policy_return(choose: str, episodes: int = 16, seed: int = 12345) -> float:
    """Mean return of the 'random' or 'stay' policy on the evaluation instances."""
    env = make_env("maif-tiny", num_envs=episodes, seed=seed, max_steps=MAX_STEPS,
                   reward="reference")
    env.reset(seed=seed)
    rng = np.random.default_rng(0)
    first: dict[int, float] = {}
    shape = (episodes, env.num_robots)
    while len(first) < episodes:
        actions = (rng.integers(0, env.num_actions, shape) if choose == "random"
                   else np.zeros(shape, np.int64))
        for ep in env.step(actions).episodes:
            first.setdefault(ep.env_index, ep.episode_return)
    return float(np.mean(list(first.values())))


def train_and_evaluate(algo: str, seed: int, root: Path) -> tuple[float, float, float]:
    """(greedy return, success rate, wall seconds) after SETTINGS[algo] steps."""
    t0 = time.perf_counter()
    tr = Trainer(_cfg(algo, seed, root), run_dir=root / f"{algo}{seed}")
    tr.run_dir.mkdir(parents=True)
    while tr.global_step < tr.cfg.train.total_steps:
        tr.train_iteration()
    tr.eval_env = make_env("maif-tiny", num_envs=16, seed=12345, max_steps=MAX_STEPS,
                           reward="reference")
    result = tr.evaluate()
    return result["eval/episodic_return"], result["eval/success_rate"], time.perf_counter() - t0


def test_reference_policies() -> None:
    """The reference points quoted above (the margins are relative to them)."""
    assert policy_return("random") == pytest.approx(-47.3, abs=0.1)
    assert policy_return("stay") == pytest.approx(-29.8, abs=0.1)


@pytest.mark.learning
@pytest.mark.parametrize("algo", list(SETTINGS))
def test_baseline_learns_on_maif_tiny(algo: str, tmp_path: Path) -> None:
    baseline = policy_return("random")
    ret, success, wall = train_and_evaluate(algo, 1, tmp_path)
    print(f"{algo}: greedy return {ret:.1f} (random {baseline:.1f}, margin {ret - baseline:.1f}),"
          f" success {success:.2f}, {SETTINGS[algo][0]} steps in {wall:.0f}s")
    assert ret >= baseline + RETURN_MARGIN[algo], (
        f"{algo} greedy return {ret:.1f} is not {RETURN_MARGIN[algo]} above the random policy's "
        f"{baseline:.1f} after {SETTINGS[algo][0]} steps")
