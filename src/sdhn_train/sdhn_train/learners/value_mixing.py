"""The off-policy value-mixing learner (QMIX, HGCN-MIX): Rashid et al., "QMIX: Monotonic Value
Function Factorisation for Deep Multi-Agent Reinforcement Learning", ICML 2018.

- Agent network: the shared recurrent actor network (MLP -> GRU -> one output per action) read as
  per-robot utilities Q_i(tau_i, .); so greedy evaluation, export to the NumPy runtime and
  checkpoints are the same code as for the PPO algorithms (greedy = argmax Q).
- Mixer: any ``Mixer`` (QMIX's hypernetwork mixer, HGCN-MIX's hypergraph mixer), monotonic in
  every Q_i.
- Learning: epsilon-greedy collection through the trainer's rollout collector, whole episodes
  into an episode replay buffer, batches of episodes re-run from a zero hidden state, 1-step TD
  targets from target networks (hard copies every ``target_update_interval`` gradient steps),
  optional double-Q, masked MSE.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from sdhn_policy.actor_torch import Actor
from sdhn_policy.weights import ActorWeights
from sdhn_train import checkpoint as ckpt
from sdhn_train.envinfo import EnvInfo
from sdhn_train.learners.base import (
    F32,
    Arrays,
    HypergraphSamples,
    JsonDict,
    NonFiniteLossError,
    actor_hidden_after,
)
from sdhn_train.learners.replay import EpisodeAssembler, EpisodeBuffer
from sdhn_train.rollout import Rollout
from sdhn_train.sections import need, need_positive, opt


@dataclass
class ValueMixingConfig:
    """The value-mixing learner's settings (config section ``qmix``, shared by QMIX and
    HGCN-MIX). They also use ppo.lr (null = the algorithm's default), ppo.gamma,
    ppo.rollout_len, ppo.reward_scale and ppo.max_grad_norm."""

    buffer_episodes: int = opt(500, "episode replay buffer capacity (whole episodes)")
    batch_episodes: int = opt(32, "episodes per gradient step")
    updates_per_rollout: int = opt(2, "gradient steps after each collected rollout")
    learning_starts: int = opt(2, "episodes in the buffer before the first gradient step")
    target_update_interval: int = opt(100, "gradient steps between hard target-network copies")
    double_q: bool = opt(True, "double Q-learning targets (argmax by the online agent net)")
    epsilon_start: float = opt(1.0, "epsilon-greedy exploration at step 0")
    epsilon_finish: float = opt(0.05, "epsilon after the anneal")
    epsilon_anneal_steps: int = opt(50_000, "team env-steps of the linear epsilon anneal")

    def validate(self) -> None:
        need_positive("qmix", {
            "buffer_episodes": self.buffer_episodes, "batch_episodes": self.batch_episodes,
            "updates_per_rollout": self.updates_per_rollout,
            "learning_starts": self.learning_starts,
            "target_update_interval": self.target_update_interval,
            "epsilon_anneal_steps": self.epsilon_anneal_steps})
        for name, eps in {"epsilon_start": self.epsilon_start,
                          "epsilon_finish": self.epsilon_finish}.items():
            need(0.0 <= eps <= 1.0, f"qmix.{name}", "[0, 1]", eps)
        need(self.batch_episodes <= self.buffer_episodes, "qmix.batch_episodes",
             f"1..qmix.buffer_episodes ({self.buffer_episodes})", self.batch_episodes)


class Mixer(nn.Module):
    """Q_tot [...] from the chosen utilities q [..., N], observations [..., N, D] and the global
    state [..., S]; monotonic in every q_i."""

    def forward(self, q: Tensor, obs: Tensor, state: Tensor) -> Tensor:
        raise NotImplementedError


class TargetNets(nn.Module):
    """Target copies of the agent network and the mixer (saved as the checkpoint's target)."""

    def __init__(self, agent: Actor, mixer: Mixer) -> None:
        super().__init__()
        self.agent, self.mixer = copy.deepcopy(agent), copy.deepcopy(mixer)
        self.requires_grad_(False)

    def sync(self, agent: Actor, mixer: nn.Module) -> None:
        self.agent.load_state_dict(agent.state_dict())
        self.mixer.load_state_dict(mixer.state_dict())


def epsilon_at(cfg: ValueMixingConfig, step: int) -> float:
    """Linear anneal from epsilon_start to epsilon_finish over epsilon_anneal_steps."""
    frac = min(1.0, step / cfg.epsilon_anneal_steps)
    return cfg.epsilon_start + frac * (cfg.epsilon_finish - cfg.epsilon_start)


class ValueMixingLearner:
    """Agent net + mixer + their targets, one Adam per module (stepped together after a joint
    gradient-norm clip: the same as one Adam over both), the episode replay buffer and the
    episodes in progress (a ``Learner``)."""

    def __init__(self, agent: Actor, mixer: Mixer, cfg: ValueMixingConfig, *, lr: float,
                 gamma: float, reward_scale: float, max_grad_norm: float, num_envs: int,
                 info: EnvInfo, rng: np.random.Generator) -> None:
        self.agent, self.mixer, self.cfg = agent, mixer, cfg
        self.gamma, self.reward_scale, self.max_grad_norm = gamma, reward_scale, max_grad_norm
        self.targets = TargetNets(agent, mixer)
        self.agent_opt = torch.optim.Adam(agent.parameters(), lr=lr, eps=1e-5)
        self.mixer_opt = torch.optim.Adam(mixer.parameters(), lr=lr, eps=1e-5)
        self.rng = rng
        dims = (info.num_robots, info.obs_size, info.state_size)
        self.buffer = EpisodeBuffer(cfg.buffer_episodes, info.max_steps, *dims)
        self.assembler = EpisodeAssembler(num_envs, info.max_steps, *dims)
        self.env_steps = 0
        self.grad_steps = 0
        self.num_updates = 0
        self.timings = {"critic": 0.0, "actor_update": 0.0}

    @property
    def actor(self) -> Actor:
        return self.agent

    def export_actor(self, version: int) -> ActorWeights:
        return self.agent.export(version)

    def initial_critic_hidden(self, batch: int) -> F32:
        return np.zeros((0, batch, 0), np.float32)  # the mixer is feed-forward

    def next_critic_hidden(self) -> F32:
        return np.zeros((0, self.assembler.length.shape[0], 0), np.float32)

    def hidden_after(self, obs: F32, state: F32) -> tuple[F32, F32]:
        return actor_hidden_after(self.agent, obs), self.initial_critic_hidden(1)

    def hypergraphs(self, rollout: Rollout) -> HypergraphSamples | None:
        return None

    @property
    def epsilon(self) -> float:
        return epsilon_at(self.cfg, self.env_steps)

    def sample_actions(self, logits: Tensor) -> tuple[Tensor, Tensor]:
        """Epsilon-greedy over utilities [X, A] -> (actions [X], log-prob of each under the
        epsilon-greedy policy). Uses torch's global RNG, like the PPO collector."""
        eps = self.epsilon
        x, a_n = logits.shape
        greedy = logits.argmax(-1)
        explore = torch.rand(x) < eps
        random_a = torch.randint(0, a_n, (x,))
        actions = torch.where(explore, random_a, greedy)
        prob = torch.where(actions == greedy, 1.0 - eps + eps / a_n, eps / a_n)
        return actions, prob.log()

    # -- the update ----------------------------------------------------------------------------

    def _utilities(self, agent: Actor, obs: Tensor) -> Tensor:
        """Q_i for every action: obs [T, K, N, D] -> [T, K, N, A] from a zero hidden state."""
        x = agent.with_robot_id(obs)
        t, k, n = x.shape[:3]
        h0 = x.new_zeros(k * n, agent.spec.gru_hidden)
        resets = torch.zeros(t, k * n, dtype=torch.bool)
        return agent.forward_sequence(x.reshape(t, k * n, -1), h0, resets).reshape(t, k, n, -1)

    def td_loss(self, batch: dict[str, np.ndarray]) -> tuple[Tensor, dict[str, float]]:
        obs = torch.from_numpy(batch["obs"])  # [l+1, K, N, D]
        state = torch.from_numpy(batch["state"])  # [l+1, K, S]
        actions = torch.from_numpy(batch["actions"])  # [l, K, N]
        rewards = torch.from_numpy(batch["rewards"]) * self.reward_scale  # [l, K]
        length = torch.from_numpy(batch["length"]).long()
        t_len = actions.shape[0]
        steps = torch.arange(t_len)[:, None]
        mask = (steps < length[None]).float()  # [l, K]
        last = steps == (length[None] - 1)
        terminal = (last & torch.from_numpy(batch["terminated"])[None]).float()

        q_all = self._utilities(self.agent, obs)  # [l+1, K, N, A]
        q_taken = q_all[:-1].gather(-1, actions[..., None]).squeeze(-1)
        q_tot = self.mixer(q_taken, obs[:-1], state[:-1])
        with torch.no_grad():
            tq_all = self._utilities(self.targets.agent, obs)[1:]
            if self.cfg.double_q:
                best = q_all[1:].detach().argmax(-1, keepdim=True)
            else:
                best = tq_all.argmax(-1, keepdim=True)
            q_next = tq_all.gather(-1, best).squeeze(-1)
            target_tot = self.targets.mixer(q_next, obs[1:], state[1:])
            y = rewards + self.gamma * (1.0 - terminal) * target_tot
        td = (q_tot - y) * mask
        loss = (td**2).sum() / mask.sum()
        metrics = {"losses/value_loss": float(loss.detach()),
                   "losses/q_taken_mean": float((q_tot.detach() * mask).sum() / mask.sum()),
                   "losses/target_mean": float((y * mask).sum() / mask.sum())}
        return loss, metrics

    def update(self, rollout: Rollout) -> dict[str, float]:
        """Store the rollout's finished episodes, then ``updates_per_rollout`` gradient steps."""
        rollout.validate()
        self.assembler.add_rollout(rollout, self.buffer)
        self.env_steps += rollout.rewards.size
        metrics: dict[str, float] = {"charts/epsilon": self.epsilon,
                                     "buffer/episodes": float(self.buffer.size)}
        if self.buffer.size < max(1, self.cfg.learning_starts):
            self.num_updates += 1
            return metrics
        sums: dict[str, float] = {}
        params = [*self.agent.parameters(), *self.mixer.parameters()]
        t0 = time.perf_counter()
        for _ in range(self.cfg.updates_per_rollout):
            loss, m = self.td_loss(self.buffer.sample(self.rng, self.cfg.batch_episodes))
            if not torch.isfinite(loss):
                raise NonFiniteLossError(f"non-finite TD loss in update {self.num_updates + 1}")
            self.agent_opt.zero_grad(set_to_none=True)
            self.mixer_opt.zero_grad(set_to_none=True)
            loss.backward()
            m["losses/grad_norm"] = float(nn.utils.clip_grad_norm_(params,
                                                                   self.max_grad_norm))
            self.agent_opt.step()
            self.mixer_opt.step()
            self.grad_steps += 1
            if self.grad_steps % self.cfg.target_update_interval == 0:
                self.targets.sync(self.agent, self.mixer)
            for k, v in m.items():
                sums[k] = sums.get(k, 0.0) + v
        self.timings["critic"] += time.perf_counter() - t0
        self.num_updates += 1
        metrics.update({k: v / self.cfg.updates_per_rollout for k, v in sums.items()})
        return metrics

    # -- checkpoint state ----------------------------------------------------------------------

    def _parts(self) -> tuple[dict[str, nn.Module], dict[str, torch.optim.Optimizer]]:
        # Slot names shared with the PPO learner (learners/base.py): the mixer is "critic".
        return ({"actor": self.agent, "critic": self.mixer, "target": self.targets},
                {"optim.actor": self.agent_opt, "optim.critic": self.mixer_opt})

    def state_dict(self) -> tuple[Arrays, JsonDict]:
        arrays, meta = ckpt.modules_state(*self._parts())
        buffer, values = self.buffer.state_dict()
        arrays.update({f"learner.buffer.{k}": v for k, v in buffer.items()})
        arrays.update({f"learner.assembler.{k}": v
                       for k, v in self.assembler.state_dict().items()})
        meta.update(num_updates=self.num_updates, rng_numpy=self.rng.bit_generator.state,
                    learner={**values, "env_steps": self.env_steps,
                             "grad_steps": self.grad_steps})
        return arrays, meta

    def load_state_dict(self, arrays: Arrays, meta: JsonDict) -> None:
        ckpt.load_modules_state(*self._parts(), arrays, meta)
        self.rng.bit_generator.state = meta["rng_numpy"]
        self.num_updates = int(meta["num_updates"])
        values = meta["learner"]
        self.buffer.load_state_dict(_strip(arrays, "learner.buffer."), values)
        self.assembler.load_state_dict(_strip(arrays, "learner.assembler."))
        self.env_steps, self.grad_steps = int(values["env_steps"]), int(values["grad_steps"])


def _strip(arrays: Arrays, prefix: str) -> Arrays:
    return {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)}
