"""The ROS trainer node's learning side, ROS-free: the algorithm's learner (the same one the
in-process trainer builds), fed with rollouts assembled from messages (``sdhn_train.transitions``)
one at a time.

    learner = StreamLearner(cfg, info, run_dir)          # seeds, builds the learner (and
                                                         # warm-starts it: actor.init_from)
    learner.resume_latest()                              # optional: newest complete checkpoint
    blob = learner.weights()                             # ActorWeights of the current version
    result = learner.train(assembled)                    # one update -> version + 1

``train`` computes the rollout's initial hidden states from the episode prefix with the current
networks (the actors' own GRU states never travel over ROS), runs ``learner.update``, bumps the
version, checkpoints atomically (before the new weights are published, so a published version
always has a checkpoint and a resumed trainer never goes backwards), and samples the critic's
hypergraphs (P_H, H, skewness) over the rollout for the ``hypergraph`` topic.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt
import torch

from sdhn_policy.weights import ActorWeights, save_actor_file
from sdhn_train import checkpoint as ckpt
from sdhn_train.algorithms.registry import get_algorithm
from sdhn_train.config import Config
from sdhn_train.env_features import featurize_assembled
from sdhn_train.envinfo import EnvInfo
from sdhn_train.learners.base import Learner
from sdhn_train.runs import seed_everything
from sdhn_train.transitions import AssembledRollout
from sdhn_train.warm_start import load_actor_into


@dataclass
class HypergraphSample:
    episode: int
    step: int
    p_h: npt.NDArray[np.float32]  # [N, M]
    incidence: npt.NDArray[np.uint8]  # [N, M]
    skewness: float


@dataclass
class UpdateResult:
    version: int
    metrics: dict[str, float]
    weights: ActorWeights
    hypergraphs: list[HypergraphSample] = field(default_factory=list)
    update_s: float = 0.0
    checkpoint_s: float = 0.0


class StreamLearner:
    def __init__(self, cfg: Config, info: EnvInfo, run_dir: Path) -> None:
        self.cfg, self.info, self.run_dir = cfg, info, run_dir
        self.rng = seed_everything(cfg.train.seed, cfg.train.deterministic, cfg.train.threads)
        self.learner: Learner = get_algorithm(cfg.algo.name).build_learner(cfg, info, self.rng)
        if cfg.actor.init_from:  # warm start, as the in-process trainer (a resume overrides it)
            load_actor_into(self.learner.actor, cfg.actor.init_from, cfg.actor.init_temperature)
        self.version = 1
        self.transitions = 0  # team env-steps learned from: names the checkpoints

    # -- weights and checkpoints ------------------------------------------------------------

    def weights(self) -> ActorWeights:
        return self.learner.export_actor(self.version)

    def save_checkpoint(self) -> Path:
        arrays, meta = ckpt.learner_state(self.learner)
        meta.update(version=self.version, transitions=self.transitions,
                    config=self.cfg.to_dict())
        path = ckpt.checkpoint_path(self.run_dir, self.transitions)
        ckpt.save_checkpoint(path, arrays, meta)
        save_actor_file(self.run_dir / "actor.safetensors", self.weights())
        ckpt.prune_checkpoints(self.run_dir, self.cfg.log.keep_checkpoints)
        return path

    def load_checkpoint(self, path: Path) -> None:
        arrays, meta = ckpt.load_checkpoint(path)
        ckpt.restore_learner_state(self.learner, arrays, meta)
        self.version = int(meta["version"])
        self.transitions = int(meta.get("transitions", 0))

    def resume_latest(self) -> Path | None:
        path = ckpt.latest_checkpoint(self.run_dir)
        if path is not None:
            self.load_checkpoint(path)
        return path

    # -- one update -------------------------------------------------------------------------

    def train(self, a: AssembledRollout, max_hypergraphs: int = 0) -> UpdateResult:
        a = featurize_assembled(a, self.info.features)  # messages carry raw observations
        actor_h, critic_h0 = self.learner.hidden_after(a.prefix_obs, a.prefix_state)
        r = a.rollout
        r.actor_h0, r.critic_h0 = actor_h[None], critic_h0
        lag = a.policy_lag(self.version)
        t0 = time.perf_counter()
        metrics = self.learner.update(r)
        t1 = time.perf_counter()
        self.version += 1
        self.transitions += r.rewards.size
        self.save_checkpoint()
        t2 = time.perf_counter()
        metrics["charts/policy_lag"] = lag
        metrics["charts/stale_action_fraction"] = float(np.mean(a.versions < self.version - 1))
        metrics["charts/rollout_reward_mean"] = float(r.rewards.mean())
        graphs = self.sample_hypergraphs(a, max_hypergraphs) if max_hypergraphs else []
        return UpdateResult(self.version, metrics, self.weights(), graphs, t1 - t0, t2 - t1)

    @torch.no_grad()
    def sample_hypergraphs(self, a: AssembledRollout, limit: int) -> list[HypergraphSample]:
        """P_H and a sampled H for up to ``limit`` evenly spaced steps of the rollout, with the
        updated critic (none for critics without hypergraphs)."""
        samples = self.learner.hypergraphs(a.rollout)
        if samples is None:
            return []
        t_len = samples.p_h.shape[0]
        picks = np.unique(np.linspace(0, t_len - 1, min(limit, t_len)).round().astype(int))
        return [HypergraphSample(a.keys[t][0], a.keys[t][1], samples.p_h[t, 0].copy(),
                                 samples.incidence[t, 0].copy(), float(samples.skewness[t, 0]))
                for t in picks]
