"""The one PPO learner shared by SDHN, MAPPO, DICG and the ROS trainer node.

``PPOLearner(actor, critic, cfg).update(rollout) -> metrics`` reads top to bottom like CleanRL's
loop: target-critic values -> bootstrap -> GAE -> epochs of minibatches (over environments, so the
recurrent actor and critic are re-run over whole stored sequences from their stored initial
hidden states) -> metrics. Only the critic differs between algorithms: any ``Critic`` below.
Equations: docs/sdhn-equations.md.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np
import torch
from torch import Tensor, nn

from sdhn_policy.actor_torch import Actor
from sdhn_policy.weights import ActorWeights
from sdhn_train import checkpoint as ckpt
from sdhn_train.data_parallel import Group
from sdhn_train.device import to_device, to_numpy
from sdhn_train.fused_gru import use_fused_gru
from sdhn_train.learners.base import (
    F32,
    Arrays,
    HypergraphSamples,
    JsonDict,
    NonFiniteLossError,
    actor_hidden_after,
    sample_categorical,
)
from sdhn_train.returns import gae_advantages, td_errors, value_targets
from sdhn_train.rollout import Rollout
from sdhn_train.sections import ConfigError, need, need_positive, opt

ModuleT = TypeVar("ModuleT", bound=nn.Module)


@dataclass
class PPOConfig:
    rollout_len: int = opt(128, "T: steps per environment per rollout")
    lr: float | None = opt(None, "actor Adam learning rate; null = algorithm default "
                                 "(sdhn 6e-4, mappo 3e-4)")
    critic_lr: float | None = opt(None, "critic Adam learning rate; null = same as lr")
    gamma: float = opt(0.99, "discount factor")
    gae_lambda: float = opt(0.95, "GAE lambda")
    clip: float = opt(0.2, "PPO ratio clip epsilon")
    epochs: int = opt(4, "passes over each rollout")
    num_minibatches: int = opt(4, "minibatches per epoch, split over environments (<= B)")
    entropy_coef: float = opt(0.01, "entropy bonus weight")
    max_grad_norm: float = opt(10.0, "gradient-norm clip for actor and critic")
    normalize_advantages: bool = opt(True, "standardise advantages per minibatch")
    concurrent_actor_critic: bool = opt(
        False, "run each minibatch's actor half on a second thread beside the critic's (same "
               "arithmetic; 2 cores, joins twice per minibatch, no per-op barrier)")
    fused_gru: bool = opt(True, "re-run stored sequences with the fused GRU (sdhn_train."
                                "fused_gru: nn.GRU's arithmetic, faster); false = nn.GRU")
    target_tau: float | None = opt(None, "target-critic soft-update rate per critic step; "
                                         "null = algorithm default (sdhn 0.01, mappo 1 = none)")
    reward_scale: float = opt(1.0, "multiply team rewards by this before GAE (logging unscaled)")
    critic_warmup_updates: int = opt(
        0, "PPO updates at the start of a run in which only the critic learns (the actor's "
           "loss is logged, its optimiser does not step): a warm-started actor is not pushed by "
           "a fresh critic's first advantages. One update = rollout_len x num_envs team steps; "
           "0 = off")
    normalize_rewards: bool = opt(False, "divide rewards by the running std of the discounted "
                                         "return (in-process trainer; logging unscaled)")

    def validate(self) -> None:
        need_positive("ppo", {"rollout_len": self.rollout_len, "epochs": self.epochs,
                              "num_minibatches": self.num_minibatches})
        for name, lr in {"lr": self.lr, "critic_lr": self.critic_lr}.items():
            need(lr is None or lr > 0, f"ppo.{name}", "a number > 0 or null", lr)
        need(0.0 <= self.gamma <= 1.0, "ppo.gamma", "[0, 1]", self.gamma)
        need(0.0 <= self.gae_lambda <= 1.0, "ppo.gae_lambda", "[0, 1]", self.gae_lambda)
        need(0.0 < self.clip < 1.0, "ppo.clip", "(0, 1)", self.clip)
        need(self.entropy_coef >= 0, "ppo.entropy_coef", ">= 0", self.entropy_coef)
        need(self.max_grad_norm > 0, "ppo.max_grad_norm", "> 0", self.max_grad_norm)
        need(self.reward_scale > 0, "ppo.reward_scale", "> 0", self.reward_scale)
        need(self.critic_warmup_updates >= 0, "ppo.critic_warmup_updates", "an integer >= 0",
             self.critic_warmup_updates)
        need(self.target_tau is None or 0.0 < self.target_tau <= 1.0, "ppo.target_tau",
             "(0, 1] or null", self.target_tau)


def resolve_ppo(cfg: PPOConfig, default_lr: float, default_target_tau: float) -> PPOConfig:
    """Fill the algorithm-dependent defaults (null lr / critic_lr / target_tau)."""
    lr = cfg.lr if cfg.lr is not None else default_lr
    return dataclasses.replace(
        cfg, lr=lr, critic_lr=cfg.critic_lr if cfg.critic_lr is not None else lr,
        target_tau=cfg.target_tau if cfg.target_tau is not None else default_target_tau)


@dataclass
class CriticOutput:
    values: Tensor  # [T, B, N]
    hiddens: Tensor  # [T, *hidden shape]: hidden *after* each step (for bootstrap values)
    aux_loss: Tensor  # scalar added to the TD loss (0 for critics without one)
    metrics: dict[str, Tensor] = field(default_factory=dict)  # detached scalars to log


class Critic(nn.Module):
    """A centralised critic for the PPO learner.

    Maps a stored sequence (obs [T, B, N, D], state [T, B, S]) to per-robot values [T, B, N]; it
    may be recurrent (``initial_state``/hidden carried across steps and rollouts) and may add an
    auxiliary loss (SDHN's lambda_CB * L_Sk). A feed-forward critic keeps the empty hidden state
    [0, B, 0] of this base class."""

    def initial_state(self, batch: int) -> Tensor:
        return torch.zeros(0, batch, 0)

    def forward_sequence(self, obs: Tensor, state: Tensor, h0: Tensor,
                         resets: Tensor) -> CriticOutput:
        raise NotImplementedError

    def value_step(self, obs: Tensor, state: Tensor, h: Tensor) -> Tensor:
        """One more step from hidden h: obs [K, N, D], state [K, S] -> values [K, N]."""
        raise NotImplementedError

    def hypergraphs(self, obs: Tensor, h0: Tensor, resets: Tensor) -> HypergraphSamples | None:
        """Hypergraphs the critic generates over a sequence; None for critics without any."""
        return None


def soft_update(target: nn.Module, source: nn.Module, rate: float) -> None:
    """theta' <- (1 - rate) theta' + rate theta (target critic of eq. v_target / td_error)."""
    with torch.no_grad():
        for tp, sp in zip(target.parameters(), source.parameters(), strict=True):
            tp.lerp_(sp, rate)


def make_target(critic: ModuleT) -> ModuleT:
    target = copy.deepcopy(critic)
    target.requires_grad_(False)
    return target


def clipped_policy_loss(logp: Tensor, logp_old: Tensor, adv: Tensor,
                        clip: float) -> tuple[Tensor, Tensor, Tensor]:
    """-E[min(eta A, clip(eta, 1-eps, 1+eps) A)] (eq. mappo); returns (loss, approx_kl,
    clipfrac)."""
    log_ratio = logp - logp_old
    ratio = log_ratio.exp()
    loss = -torch.min(ratio * adv, ratio.clamp(1.0 - clip, 1.0 + clip) * adv).mean()
    with torch.no_grad():
        approx_kl = ((ratio - 1.0) - log_ratio).mean()  # k3 estimator
        clipfrac = ((ratio - 1.0).abs() > clip).float().mean()
    return loss, approx_kl, clipfrac


def explained_variance(pred: Tensor, target: Tensor) -> float:
    var = target.var()
    return float("nan") if var == 0 else float(1.0 - (target - pred).var() / var)


class PPOLearner:
    """Owns the actor, critic, target critic and their optimisers (a ``Learner``)."""

    def __init__(self, actor: Actor, critic: Critic, cfg: PPOConfig,
                 rng: np.random.Generator | None = None) -> None:
        if cfg.lr is None or cfg.critic_lr is None or cfg.target_tau is None:
            raise ConfigError("PPOConfig must be resolved (resolve_ppo) before use")
        self._actor, self.critic, self.cfg = actor, critic, cfg
        use_fused_gru(actor, cfg.fused_gru)
        use_fused_gru(critic, cfg.fused_gru)
        self.target_tau = cfg.target_tau
        self.target_critic = make_target(critic)
        self.actor_opt = torch.optim.Adam(actor.parameters(), lr=cfg.lr, eps=1e-5)
        self.critic_opt = torch.optim.Adam(critic.parameters(), lr=cfg.critic_lr, eps=1e-5)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.num_updates = 0
        self._next_critic_hidden: F32 | None = None  # critic_h0 for the next rollout
        self.timings = {"critic": 0.0, "actor_update": 0.0}  # wall seconds (benchmark shares)
        self._executor: ThreadPoolExecutor | None = None  # ppo.concurrent_actor_critic
        # train.learner_processes > 1: this replica's group; gradients, the advantage
        # statistics and the logged metrics are averaged over it (sdhn_train.data_parallel)
        self.group: Group | None = None
        self.device = torch.device("cpu")

    def to(self, device: torch.device) -> PPOLearner:
        """Move the networks (and so what the optimisers step) to ``device`` (train.device);
        every tensor an update builds is made there. Before the first update: the optimisers'
        state, created at the first step, is then made on the device too."""
        for module in (self.actor, self.critic, self.target_critic):
            module.to(device)
        self.device = device
        return self

    @property
    def actor(self) -> Actor:
        return self._actor

    def export_actor(self, version: int) -> ActorWeights:
        return self.actor.export(version)

    def sample_actions(self, logits: Tensor) -> tuple[Tensor, Tensor]:
        return sample_categorical(logits)

    def initial_critic_hidden(self, batch: int) -> F32:
        return to_numpy(self.critic.initial_state(batch))

    def next_critic_hidden(self) -> F32:
        if self._next_critic_hidden is None:
            raise RuntimeError("next_critic_hidden before the first update")
        return self._next_critic_hidden

    @torch.no_grad()
    def hidden_after(self, obs: F32, state: F32) -> tuple[F32, F32]:
        dev = self.device
        critic_h = self.target_critic.initial_state(1).to(dev)
        p = obs.shape[0]
        if p:
            out = self.target_critic.forward_sequence(
                to_device(obs, dev)[:, None], to_device(state, dev)[:, None], critic_h,
                torch.zeros(p, 1, dtype=torch.bool, device=dev))
            critic_h = out.hiddens[-1]
        return actor_hidden_after(self.actor, obs), to_numpy(critic_h)

    @torch.no_grad()
    def hypergraphs(self, rollout: Rollout) -> HypergraphSamples | None:
        dev = self.device
        h0 = (to_device(rollout.critic_h0, dev) if rollout.critic_h0 is not None
              else self.critic.initial_state(rollout.shape[1]).to(dev))
        return self.critic.hypergraphs(to_device(rollout.obs, dev), h0,
                                       to_device(rollout.resets(), dev))

    # -- checkpoint state -----------------------------------------------------------------

    def _parts(self) -> tuple[dict[str, nn.Module], dict[str, torch.optim.Optimizer]]:
        return ({"actor": self.actor, "critic": self.critic, "target": self.target_critic},
                {"optim.actor": self.actor_opt, "optim.critic": self.critic_opt})

    def state_dict(self) -> tuple[Arrays, JsonDict]:
        arrays, meta = ckpt.modules_state(*self._parts())
        meta.update(num_updates=self.num_updates, rng_numpy=self.rng.bit_generator.state)
        return arrays, meta

    def load_state_dict(self, arrays: Arrays, meta: JsonDict) -> None:
        ckpt.load_modules_state(*self._parts(), arrays, meta)
        self.rng.bit_generator.state = meta["rng_numpy"]
        self.num_updates = int(meta["num_updates"])

    # -- pieces of the update -------------------------------------------------------------

    @torch.no_grad()
    def _targets(self, r: dict[str, Tensor], h0: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Target-critic values, GAE advantages and value targets; also sets the critic carry."""
        out = self.target_critic.forward_sequence(r["obs"], r["state"], h0, r["resets"])
        values = out.values  # V(s^t; theta')  [T, B, N]
        # V(s^{t+1}; theta'): the next step's value where the episode continues, else the value
        # of the episode's final observation from the hidden state after step t.
        next_values = torch.zeros_like(values)
        next_values[:-1] = values[1:]
        need = r["done"].clone()
        need[-1] = True
        t_idx, b_idx = need.nonzero(as_tuple=True)
        if len(t_idx):
            h = out.hiddens[t_idx, :, b_idx].movedim(0, -2) if h0.numel() else h0[:, :0]
            next_values[t_idx, b_idx] = self.target_critic.value_step(
                r["final_obs"][t_idx, b_idx], r["final_state"][t_idx, b_idx], h)
        rewards = r["rewards"] * self.cfg.reward_scale
        deltas = td_errors(rewards, values, next_values, r["terminated"], self.cfg.gamma)
        adv = gae_advantages(deltas, r["done"], self.cfg.gamma, self.cfg.gae_lambda)
        carry = out.hiddens[-1] * (~r["done"][-1]).to(values.dtype)[None, :, None] \
            if h0.numel() else h0
        self._next_critic_hidden = to_numpy(carry)
        return values, adv, value_targets(adv, values)

    def _actor_logits(self, r: dict[str, Tensor], envs: Tensor) -> Tensor:
        obs = r["actor_in"][:, envs]  # [T, b, N, in]
        t, b, n = obs.shape[:3]
        resets = r["resets"][:, envs, None].expand(t, b, n).reshape(t, b * n)
        h0 = r["actor_h0"][envs].reshape(b * n, -1)
        return self.actor.forward_sequence(obs.reshape(t, b * n, -1), h0, resets).reshape(
            t, b, n, -1)

    def _actor_loss(self, r: dict[str, Tensor], envs: Tensor,
                    adv: Tensor) -> tuple[Tensor, dict[str, Tensor]]:
        t0 = time.perf_counter()
        cfg = self.cfg
        logits = self._actor_logits(r, envs)
        logp_all = torch.log_softmax(logits, dim=-1)
        logp = logp_all.gather(-1, r["actions"][:, envs, :, None]).squeeze(-1)
        entropy = -(logp_all.exp() * logp_all).sum(-1).mean()
        mb_adv = adv[:, envs]
        if cfg.normalize_advantages and self.group is not None:  # over the whole minibatch
            mean, std = self.group.mean_std(mb_adv)
            mb_adv = (mb_adv - mean) / (std + 1e-8)
        elif cfg.normalize_advantages and mb_adv.numel() > 1:
            mb_adv = (mb_adv - mb_adv.mean()) / (mb_adv.std() + 1e-8)
        pg_loss, approx_kl, clipfrac = clipped_policy_loss(
            logp, r["logp_old"][:, envs], mb_adv, cfg.clip)
        actor_loss = pg_loss - cfg.entropy_coef * entropy
        self.timings["actor_update"] += time.perf_counter() - t0
        return actor_loss, {"losses/policy_loss": pg_loss, "losses/entropy": entropy,
                            "losses/approx_kl": approx_kl, "losses/clipfrac": clipfrac}

    def _critic_loss(self, r: dict[str, Tensor], envs: Tensor, targets: Tensor,
                     h0: Tensor) -> tuple[Tensor, dict[str, Tensor]]:
        t0 = time.perf_counter()
        out = self.critic.forward_sequence(r["obs"][:, envs], r["state"][:, envs],
                                           h0[:, envs], r["resets"][:, envs])
        td_loss = ((out.values - targets[:, envs]) ** 2).mean()  # eq. loss
        critic_loss = td_loss + out.aux_loss  # eq. total_loss
        self.timings["critic"] += time.perf_counter() - t0
        return critic_loss, {"losses/value_loss": td_loss, **out.metrics}

    def _actor_step(self, loss: Tensor) -> Tensor:
        t0 = time.perf_counter()
        self.actor_opt.zero_grad(set_to_none=True)
        loss.backward()
        if self.group is not None:
            self.group.average_grads(self.actor.parameters())
        norm = nn.utils.clip_grad_norm_(self.actor.parameters(), self.cfg.max_grad_norm)
        self.actor_opt.step()
        self.timings["actor_update"] += time.perf_counter() - t0
        return norm

    def _critic_step(self, loss: Tensor) -> Tensor:
        t0 = time.perf_counter()
        self.critic_opt.zero_grad(set_to_none=True)
        loss.backward()
        if self.group is not None:
            self.group.average_grads(self.critic.parameters())
        norm = nn.utils.clip_grad_norm_(self.critic.parameters(), self.cfg.max_grad_norm)
        self.critic_opt.step()
        soft_update(self.target_critic, self.critic, self.target_tau)
        self.timings["critic"] += time.perf_counter() - t0
        return norm

    def _minibatch(self, r: dict[str, Tensor], envs: Tensor, adv: Tensor, targets: Tensor,
                   h0: Tensor) -> dict[str, Tensor]:
        """One actor step and one critic step on the environments ``envs``. The two share no
        tensor that either changes, so with ``ppo.concurrent_actor_critic`` the actor's half
        runs on a second thread while the critic's runs here: same arithmetic, same RNG draws
        (only the critic draws), two joins per minibatch."""
        pool = self._pool()
        if pool is None:
            actor_loss, a_stats = self._actor_loss(r, envs, adv)
            critic_loss, c_stats = self._critic_loss(r, envs, targets, h0)
        else:
            fut = pool.submit(self._actor_loss, r, envs, adv)
            critic_loss, c_stats = self._critic_loss(r, envs, targets, h0)
            actor_loss, a_stats = fut.result()
        finite = bool(torch.isfinite(actor_loss) and torch.isfinite(critic_loss))
        if self.group is not None:  # every replica raises, or none (no peer left waiting)
            finite = self.group.all_true(finite)
        if not finite:
            raise NonFiniteLossError(
                f"non-finite loss in update {self.num_updates + 1}: actor "
                f"{float(actor_loss)}, critic {float(critic_loss)}")
        if self.num_updates < self.cfg.critic_warmup_updates:  # the critic warms up alone
            a_norm = torch.zeros((), device=self.device)
            c_norm = self._critic_step(critic_loss)
        elif pool is None:
            a_norm = self._actor_step(actor_loss)
            c_norm = self._critic_step(critic_loss)
        else:
            fut_norm = pool.submit(self._actor_step, actor_loss)
            c_norm = self._critic_step(critic_loss)
            a_norm = fut_norm.result()
        return {**a_stats, **c_stats, "losses/actor_grad_norm": a_norm,
                "losses/critic_grad_norm": c_norm}

    def _pool(self) -> ThreadPoolExecutor | None:
        if not self.cfg.concurrent_actor_critic:
            return None
        if self._executor is None:
            threads = torch.get_num_threads()  # the worker keeps the trainer's thread count
            self._executor = ThreadPoolExecutor(
                1, "ppo-actor", initializer=torch.set_num_threads, initargs=(threads,))
        return self._executor

    # -- the update -----------------------------------------------------------------------

    def minibatch_envs(self, b: int) -> list[Tensor]:
        """One epoch's minibatches: a permutation of the b environments in
        ``num_minibatches`` chunks (with data-parallel ranks: of this process's environments,
        the same chunk sizes in every process)."""
        num_mb = max(1, min(self.cfg.num_minibatches, b))
        return list(to_device(self.rng.permutation(b), self.device).chunk(num_mb))

    def update(self, rollout: Rollout) -> dict[str, float]:
        """One PPO update on a rollout; returns scalar metrics keyed by TensorBoard tag."""
        rollout.validate()
        cfg = self.cfg
        dev = self.device
        r = {name: to_device(a, dev) for name, a in (
            ("obs", rollout.obs), ("state", rollout.state), ("actions", rollout.actions),
            ("logp_old", rollout.log_probs), ("rewards", rollout.rewards),
            ("terminated", rollout.terminated), ("done", rollout.done),
            ("resets", rollout.resets()), ("final_obs", rollout.final_obs),
            ("final_state", rollout.final_state), ("actor_h0", rollout.actor_h0))}
        # the actor's input (observation + one-hot robot id) does not depend on the parameters:
        # built once per update, not once per minibatch and epoch
        r["actor_in"] = self.actor.with_robot_id(r["obs"])
        b = rollout.shape[1]
        h0 = (to_device(rollout.critic_h0, dev) if rollout.critic_h0 is not None
              else self.critic.initial_state(b).to(dev))
        t0 = time.perf_counter()
        values, adv, targets = self._targets(r, h0)
        self.timings["critic"] += time.perf_counter() - t0

        sums: dict[str, float] = {}
        count = 0
        for _epoch in range(cfg.epochs):
            for envs in self.minibatch_envs(b):
                step = self._minibatch(r, envs, adv, targets, h0)
                for k, v in step.items():
                    sums[k] = sums.get(k, 0.0) + float(v.detach())
                count += 1
        self.num_updates += 1
        metrics = {k: v / count for k, v in sums.items()}
        metrics["losses/explained_variance"] = explained_variance(values, targets)
        metrics["losses/advantage_mean"] = float(adv.mean())
        if self.group is not None:  # explained variance: the mean of the replicas' figures
            metrics = self.group.average_metrics(metrics)
        return metrics
