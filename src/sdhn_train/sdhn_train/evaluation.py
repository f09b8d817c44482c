"""Greedy evaluation on the training and the held-out instance sets, success and makespan first.

MAIF: every one of the first ``eval.instances`` instances of each set (ids 0..k-1), one greedy
episode each (``round_robin`` order, so env b plays instance b). Tags (CSV and TensorBoard)::

    eval/success_rate  eval/makespan  eval/heldout_success_rate  eval/heldout_makespan
    eval/episodic_return  eval/heldout_episodic_return  (under the reward named in the summary)

``makespan`` is the mean over completed episodes; it is absent (NC) when none completed.
RWARE has no instance sets: ``eval.episodes`` episodes from ``eval.seed`` as before, and no
success; its task measure is ``eval/deliveries``, requested shelves delivered per episode.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from sdhn_policy.actor_torch import Actor
from sdhn_sim.envs.api import BatchedEnv, EpisodeStats
from sdhn_train.collector import evaluate_greedy
from sdhn_train.config import Config
from sdhn_train.env_features import EnvFactory, make_training_env

MAIF_SET_SIZE = 100


def make_eval_envs(cfg: Config, factory: EnvFactory) -> dict[str, BatchedEnv]:
    """{"": training-set env, "heldout_": held-out env} (MAIF, at the task's 500-step limit even
    when training uses shorter episodes), {"": env} otherwise; {} if evaluation is off. Keys are
    the tag infix of each set's metrics."""
    if cfg.eval.interval <= 0:
        return {}
    if not cfg.env.name.startswith("maif"):
        return {"": make_training_env(cfg, factory, cfg.eval.episodes, cfg.eval.seed,
                                      conditions=False)}
    k = min(cfg.eval.instances, MAIF_SET_SIZE)
    cfg = copy.deepcopy(cfg)
    cfg.env.max_steps = None  # success and makespan always at the task's own step limit (500)
    kw: dict[str, Any] = {"instance_ids": list(range(k)), "instance_order": "round_robin"}
    return {prefix: make_training_env(cfg, factory, k, cfg.eval.seed, conditions=False,
                                      instance_set=which, **kw)
            for prefix, which in (("", "train"), ("heldout_", "heldout"))}


def set_metrics(infix: str, episodes: list[EpisodeStats]) -> dict[str, float]:
    """Success rate and makespan (completed episodes only) first, then return and the rest."""
    if not episodes:
        return {}
    out = {f"eval/{infix}success_rate": float(np.mean([e.completed for e in episodes]))}
    done = [e.makespan for e in episodes if e.makespan is not None]
    if done:
        out[f"eval/{infix}makespan"] = float(np.mean(done))
    delivered = [e.deliveries for e in episodes if e.deliveries is not None]
    if delivered:  # environments with a delivery count (RWARE)
        out[f"eval/{infix}deliveries"] = float(np.mean(delivered))
    out[f"eval/{infix}episodic_return"] = float(np.mean([e.episode_return for e in episodes]))
    out[f"eval/{infix}episode_length"] = float(np.mean([e.length for e in episodes]))
    out[f"eval/{infix}collisions"] = float(np.mean([e.collisions for e in episodes]))
    return out


def evaluate_sets(envs: dict[str, BatchedEnv], actor: Actor, seed: int) -> dict[str, float]:
    out: dict[str, float] = {}
    for infix, env in envs.items():
        out.update(set_metrics(infix, evaluate_greedy(env, actor, seed)))
    return out


def headline(metrics: dict[str, float]) -> str:
    """One line: success and makespan on both sets (NC where nothing completed), then return."""
    def ms(infix: str) -> str:
        v = metrics.get(f"eval/{infix}makespan")
        return "NC" if v is None else f"{v:.1f}"

    parts = [f"success {metrics.get('eval/success_rate', float('nan')):.2f}",
             f"makespan {ms('')}"]
    if "eval/heldout_success_rate" in metrics:
        parts += [f"held-out success {metrics['eval/heldout_success_rate']:.2f}",
                  f"makespan {ms('heldout_')}"]
    if "eval/deliveries" in metrics:
        parts.append(f"deliveries {metrics['eval/deliveries']:.1f}")
    parts.append(f"return {metrics.get('eval/episodic_return', float('nan')):.1f}")
    return ", ".join(parts)
