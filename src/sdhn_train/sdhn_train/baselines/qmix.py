"""QMIX: Rashid, T., Samvelyan, M., de Witt, C.S., Farquhar, G., Foerster, J.N., Whiteson, S.,
"QMIX: Monotonic Value Function Factorisation for Deep Multi-Agent Reinforcement Learning",
ICML 2018.

- Agent network: the shared recurrent actor network (MLP -> GRU -> one output per action) read as
  per-robot utilities Q_i(tau_i, .); so greedy evaluation, export to the NumPy runtime and
  checkpoints are the same code as for the PPO algorithms (greedy = argmax Q).
- Mixer: Q_tot = w2(s)^T ELU(W1(s)^T Q + b1(s)) + V(s), with hypernetworks producing W1 and w2
  and an absolute value keeping them non-negative (monotonic in every Q_i).
- Learner (``ValueMixingLearner``, shared with HGCN-MIX): epsilon-greedy collection through the
  trainer's rollout collector, whole episodes into an episode replay buffer, batches of episodes
  re-run from a zero hidden state, 1-step TD targets from target networks (hard copies every
  ``qmix.target_update_interval`` gradient steps), optional double-Q, masked MSE.
"""

from __future__ import annotations

import copy
import time
from typing import TYPE_CHECKING, ClassVar, TypeAlias

import numpy as np
import torch
from torch import Tensor, nn

from sdhn_policy.actor_torch import Actor
from sdhn_policy.weights import ActorWeights
from sdhn_train.baselines.replay import EpisodeAssembler, EpisodeBuffer
from sdhn_train.config import Config, PPOConfig, QMIXConfig
from sdhn_train.ppo import NonFiniteLossError
from sdhn_train.rollout import Rollout

if TYPE_CHECKING:
    from sdhn_train.algorithms import EnvInfo
    from sdhn_train.baselines.hgcn_mix import HGCNMixer

MixerModule: TypeAlias = "QMixer | HGCNMixer"


class QMixer(nn.Module):
    """Monotonic mixing network with hypernetworks on the global state (Rashid et al. 2018)."""

    def __init__(self, state_size: int, num_robots: int, embed: int = 32,
                 hypernet_hidden: int = 64) -> None:
        super().__init__()
        self.num_robots, self.embed = num_robots, embed
        self.hyper_w1 = nn.Sequential(nn.Linear(state_size, hypernet_hidden), nn.ReLU(),
                                      nn.Linear(hypernet_hidden, num_robots * embed))
        self.hyper_b1 = nn.Linear(state_size, embed)
        self.hyper_w2 = nn.Sequential(nn.Linear(state_size, hypernet_hidden), nn.ReLU(),
                                      nn.Linear(hypernet_hidden, embed))
        self.hyper_v = nn.Sequential(nn.Linear(state_size, embed), nn.ReLU(),
                                     nn.Linear(embed, 1))

    def initial_state(self, batch: int) -> Tensor:
        return torch.zeros(0, batch, 0)

    def forward(self, q: Tensor, obs: Tensor, state: Tensor) -> Tensor:
        lead = q.shape[:-1]
        w1 = self.hyper_w1(state).abs().reshape(*lead, self.num_robots, self.embed)
        hidden = torch.nn.functional.elu((q.unsqueeze(-2) @ w1).squeeze(-2) + self.hyper_b1(state))
        w2 = self.hyper_w2(state).abs()
        return (hidden * w2).sum(-1) + self.hyper_v(state).squeeze(-1)


class TargetNets(nn.Module):
    """Target copies of the agent network and the mixer (saved as the checkpoint's target)."""

    def __init__(self, agent: Actor, mixer: MixerModule) -> None:
        super().__init__()
        self.agent, self.mixer = copy.deepcopy(agent), copy.deepcopy(mixer)
        self.requires_grad_(False)

    def sync(self, agent: Actor, mixer: nn.Module) -> None:
        self.agent.load_state_dict(agent.state_dict())
        self.mixer.load_state_dict(mixer.state_dict())


def epsilon_at(cfg: QMIXConfig, step: int) -> float:
    """Linear anneal from epsilon_start to epsilon_finish over epsilon_anneal_steps."""
    frac = min(1.0, step / cfg.epsilon_anneal_steps)
    return cfg.epsilon_start + frac * (cfg.epsilon_finish - cfg.epsilon_start)


class ValueMixingLearner:
    """Off-policy value-mixing learner (QMIX, HGCN-MIX) with the trainer's learner interface:
    ``actor`` (agent net), ``critic`` (mixer), ``target_critic``, two Adam optimisers (one per
    module, stepped together after a joint gradient-norm clip: the same as one Adam over both),
    ``update(rollout)``, ``sample_actions`` (epsilon-greedy, for the collector),
    ``extra_state``/``load_extra_state`` (replay buffer and episodes in progress, for exact
    resume)."""

    def __init__(self, agent: Actor, mixer: MixerModule, cfg: QMIXConfig, ppo: PPOConfig, *,
                 num_envs: int, info: EnvInfo, rng: np.random.Generator) -> None:
        assert ppo.lr is not None
        self.actor, self.critic, self.cfg, self.ppo = agent, mixer, cfg, ppo
        self.target_critic = TargetNets(agent, mixer)
        self.actor_opt = torch.optim.Adam(agent.parameters(), lr=ppo.lr, eps=1e-5)
        self.critic_opt = torch.optim.Adam(mixer.parameters(), lr=ppo.lr, eps=1e-5)
        self.rng = rng
        dims = (info.num_robots, info.obs_size, info.state_size)
        self.buffer = EpisodeBuffer(cfg.buffer_episodes, info.max_steps, *dims)
        self.assembler = EpisodeAssembler(num_envs, info.max_steps, *dims)
        self.env_steps = 0
        self.grad_steps = 0
        self.num_updates = 0
        self.next_critic_hidden: np.ndarray | None = np.zeros((0, num_envs, 0), np.float32)
        self.timings = {"critic": 0.0, "actor_update": 0.0}

    def export_actor(self, version: int) -> ActorWeights:
        return self.actor.export(version)

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
        rewards = torch.from_numpy(batch["rewards"]) * self.ppo.reward_scale  # [l, K]
        length = torch.from_numpy(batch["length"]).long()
        t_len = actions.shape[0]
        steps = torch.arange(t_len)[:, None]
        mask = (steps < length[None]).float()  # [l, K]
        last = steps == (length[None] - 1)
        terminal = (last & torch.from_numpy(batch["terminated"])[None]).float()

        q_all = self._utilities(self.actor, obs)  # [l+1, K, N, A]
        q_taken = q_all[:-1].gather(-1, actions[..., None]).squeeze(-1)
        q_tot = self.critic(q_taken, obs[:-1], state[:-1])
        with torch.no_grad():
            tq_all = self._utilities(self.target_critic.agent, obs)[1:]
            if self.cfg.double_q:
                best = q_all[1:].detach().argmax(-1, keepdim=True)
            else:
                best = tq_all.argmax(-1, keepdim=True)
            q_next = tq_all.gather(-1, best).squeeze(-1)
            target_tot = self.target_critic.mixer(q_next, obs[1:], state[1:])
            y = rewards + self.ppo.gamma * (1.0 - terminal) * target_tot
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
        params = [*self.actor.parameters(), *self.critic.parameters()]
        t0 = time.perf_counter()
        for _ in range(self.cfg.updates_per_rollout):
            loss, m = self.td_loss(self.buffer.sample(self.rng, self.cfg.batch_episodes))
            if not torch.isfinite(loss):
                raise NonFiniteLossError(f"non-finite TD loss in update {self.num_updates + 1}")
            self.actor_opt.zero_grad(set_to_none=True)
            self.critic_opt.zero_grad(set_to_none=True)
            loss.backward()
            m["losses/grad_norm"] = float(nn.utils.clip_grad_norm_(params,
                                                                   self.ppo.max_grad_norm))
            self.actor_opt.step()
            self.critic_opt.step()
            self.grad_steps += 1
            if self.grad_steps % self.cfg.target_update_interval == 0:
                self.target_critic.sync(self.actor, self.critic)
            for k, v in m.items():
                sums[k] = sums.get(k, 0.0) + v
        self.timings["critic"] += time.perf_counter() - t0
        self.num_updates += 1
        metrics.update({k: v / self.cfg.updates_per_rollout for k, v in sums.items()})
        return metrics

    # -- checkpoint extras ---------------------------------------------------------------------

    def extra_state(self) -> tuple[dict[str, np.ndarray], dict[str, int]]:
        arrays, values = self.buffer.state_dict()
        out = {f"buffer.{k}": v for k, v in arrays.items()}
        out.update({f"assembler.{k}": v for k, v in self.assembler.state_dict().items()})
        return out, {**values, "env_steps": self.env_steps, "grad_steps": self.grad_steps}

    def load_extra_state(self, arrays: dict[str, np.ndarray], values: dict[str, int]) -> None:
        self.buffer.load_state_dict(
            {k[7:]: v for k, v in arrays.items() if k.startswith("buffer.")}, values)
        self.assembler.load_state_dict(
            {k[10:]: v for k, v in arrays.items() if k.startswith("assembler.")})
        self.env_steps, self.grad_steps = int(values["env_steps"]), int(values["grad_steps"])


def build_value_mixing_learner(cfg: Config, info: EnvInfo, rng: np.random.Generator,
                               mixer: MixerModule, default_lr: float) -> ValueMixingLearner:
    """Agent net (the shared actor architecture) + ``mixer`` + the value-mixing learner."""
    from sdhn_train.algorithms import actor_spec  # the registry imports this module

    ppo = copy.copy(cfg.ppo)
    ppo.lr = ppo.lr if ppo.lr is not None else default_lr
    agent = Actor(actor_spec(cfg, info))
    return ValueMixingLearner(agent, mixer, cfg.qmix, ppo, num_envs=cfg.env.num_envs, info=info,
                              rng=rng)


class QMIX:
    """QMIX (Rashid et al. 2018): monotonic hypernetwork mixer on the global state."""

    name: ClassVar[str] = "qmix"
    default_lr: ClassVar[float] = 5e-4
    default_target_tau: ClassVar[float] = 1.0

    def build_learner(self, cfg: Config, info: EnvInfo,
                      rng: np.random.Generator) -> ValueMixingLearner:
        mixer = QMixer(info.state_size, info.num_robots, cfg.qmix.mixer_embed,
                       cfg.qmix.hypernet_hidden)
        return build_value_mixing_learner(cfg, info, rng, mixer, self.default_lr)
