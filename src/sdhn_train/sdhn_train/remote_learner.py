"""The trainer node's learning side, ROS-free: the SAME ``PPOLearner`` as the in-process trainer,
fed with rollouts assembled from messages (``sdhn_train.transitions``).

    learner = RemoteLearner(cfg, info, run_dir)          # seeds, builds actor + critic + PPO
    learner.resume_latest()                              # optional: newest complete checkpoint
    blob = learner.weights()                             # ActorWeights of the current version
    result = learner.train(assembled)                    # one PPO update -> version + 1

``train`` computes the rollout's initial hidden states from the episode prefix with the current
networks (the actors' own GRU states never travel over ROS), runs ``learner.update``, bumps the
version, checkpoints atomically (before the new weights are published, so a published version
always has a checkpoint and a resumed trainer never goes backwards), and samples the critic's
hypergraphs (P_H, H, skewness) over the rollout for the ``hypergraph`` topic.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np
import numpy.typing as npt
import torch

from sdhn_policy.weights import ActorWeights, save_actor_file
from sdhn_train import checkpoint as ckpt
from sdhn_train.algorithms import EnvInfo, build_learner
from sdhn_train.config import Config
from sdhn_train.critics import Critic, SDHNCritic
from sdhn_train.env_features import featurize_assembled
from sdhn_train.hypergraph import binary_concrete
from sdhn_train.skewness import hyperedge_degrees, sample_skewness, squashed_skewness
from sdhn_train.trainer import seed_everything
from sdhn_train.transitions import AssembledRollout

CHECKPOINT_DIR = "checkpoints"
KEEP_CHECKPOINTS = 3
_NAME = re.compile(r"^version_(\d{6,})\.json$")


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


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The newest complete checkpoint (its JSON is written last) under run_dir, or None."""
    found = []
    directory = run_dir / CHECKPOINT_DIR
    if directory.is_dir():
        for p in directory.iterdir():
            m = _NAME.match(p.name)
            if m and p.with_suffix(".safetensors").is_file():
                found.append((int(m.group(1)), p.with_suffix("")))
    return max(found)[1] if found else None


class RemoteLearner:
    def __init__(self, cfg: Config, info: EnvInfo, run_dir: Path) -> None:
        self.cfg, self.info, self.run_dir = cfg, info, run_dir
        self.rng = seed_everything(cfg.train.seed, cfg.train.deterministic, cfg.train.threads)
        self.learner = build_learner(cfg, info, self.rng)
        self.version = 1
        self.transitions = 0

    # -- weights and checkpoints ------------------------------------------------------------

    def weights(self) -> ActorWeights:
        return self.learner.export_actor(self.version)

    def save_checkpoint(self) -> Path:
        arrays, meta = ckpt.learner_state(self.learner)
        meta.update(version=self.version, transitions=self.transitions,
                    config=self.cfg.to_dict())
        path = self.run_dir / CHECKPOINT_DIR / f"version_{self.version:06d}"
        ckpt.save_checkpoint(path, arrays, meta)
        save_actor_file(self.run_dir / "actor.safetensors", self.weights())
        self._prune()
        return path

    def _prune(self) -> None:
        directory = self.run_dir / CHECKPOINT_DIR
        names = sorted(p for p in directory.glob("version_*.json") if _NAME.match(p.name))
        for old in names[:-KEEP_CHECKPOINTS]:
            old.unlink(missing_ok=True)  # the JSON first: a checkpoint without it is not used
            old.with_suffix(".safetensors").unlink(missing_ok=True)

    def load_checkpoint(self, path: Path) -> None:
        arrays, meta = ckpt.load_checkpoint(path)
        ckpt.restore_learner_state(self.learner, arrays, meta)
        self.version = int(meta["version"])
        self.transitions = int(meta.get("transitions", 0))

    def resume_latest(self) -> Path | None:
        path = latest_checkpoint(self.run_dir)
        if path is not None:
            self.load_checkpoint(path)
        return path

    # -- one update -------------------------------------------------------------------------

    @torch.no_grad()
    def initial_hidden(self, a: AssembledRollout) -> tuple[np.ndarray, np.ndarray]:
        """(actor_h0 [1, N, H], critic_h0) after the episode prefix, with the current nets."""
        lr = self.learner
        n = self.info.num_robots
        p = a.prefix_obs.shape[0]
        actor_h = torch.zeros(n, lr.actor.spec.gru_hidden)
        target = cast(Critic, lr.target_critic)  # a deep copy of the critic (make_target)
        critic_h = target.initial_state(1)
        if p:
            obs = torch.from_numpy(a.prefix_obs)  # [P, N, D]
            x = lr.actor.with_robot_id(obs)  # [P, N, in]
            for t in range(p):
                _, actor_h = lr.actor.step(x[t], actor_h)
            out = target.forward_sequence(
                obs[:, None], torch.from_numpy(a.prefix_state)[:, None], critic_h,
                torch.zeros(p, 1, dtype=torch.bool))
            critic_h = out.hiddens[-1]
        return actor_h[None].numpy().copy(), critic_h.numpy().copy()

    def train(self, a: AssembledRollout, max_hypergraphs: int = 0) -> UpdateResult:
        a = featurize_assembled(a, self.info.features)  # messages carry raw observations
        actor_h0, critic_h0 = self.initial_hidden(a)
        r = a.rollout
        r.actor_h0, r.critic_h0 = actor_h0, critic_h0
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
        graphs = self.sample_hypergraphs(a, critic_h0, max_hypergraphs) if max_hypergraphs else []
        return UpdateResult(self.version, metrics, self.weights(), graphs, t1 - t0, t2 - t1)

    @torch.no_grad()
    def sample_hypergraphs(self, a: AssembledRollout, critic_h0: np.ndarray,
                           limit: int) -> list[HypergraphSample]:
        """P_H and a sampled H for up to ``limit`` evenly spaced steps of the rollout (SDHN only),
        with the updated critic."""
        critic = self.learner.critic
        if not isinstance(critic, SDHNCritic):
            return []
        r = a.rollout
        obs = torch.from_numpy(r.obs)
        logits, _ = critic.generator.forward_sequence(
            obs, torch.from_numpy(critic_h0), torch.from_numpy(r.resets()))
        incidence, _ = binary_concrete(logits, critic.tau, critic.noise, critic.stochastic)
        sk = squashed_skewness(sample_skewness(hyperedge_degrees(incidence)))  # [T, 1]
        p_h = torch.sigmoid(logits)
        t_len = obs.shape[0]
        picks = np.unique(np.linspace(0, t_len - 1, min(limit, t_len)).round().astype(int))
        return [HypergraphSample(a.keys[t][0], a.keys[t][1], p_h[t, 0].numpy().copy(),
                                 incidence[t, 0].numpy().astype(np.uint8), float(sk[t, 0]))
                for t in picks]
