"""The one PPO update shared by SDHN, MAPPO and the ROS trainer node.

``PPOLearner(actor, critic, cfg).update(rollout) -> metrics`` reads top to bottom like CleanRL's
loop: target-critic values -> bootstrap -> GAE -> epochs of minibatches (over environments, so the
recurrent actor and critic are re-run over whole stored sequences from their stored initial
hidden states) -> metrics. Only the critic differs between algorithms.
"""

from __future__ import annotations

import time

import numpy as np
import torch
from torch import Tensor, nn

from sdhn_policy.actor_torch import Actor
from sdhn_policy.weights import ActorWeights
from sdhn_train.config import PPOConfig
from sdhn_train.critics import Critic, make_target, soft_update
from sdhn_train.returns import gae_advantages, td_errors, value_targets
from sdhn_train.rollout import Rollout


class NonFiniteLossError(RuntimeError):
    """A loss became NaN/inf; training must stop."""


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
    """Owns the actor, critic, target critic and their optimisers."""

    def __init__(self, actor: Actor, critic: Critic, cfg: PPOConfig,
                 rng: np.random.Generator | None = None) -> None:
        if cfg.lr is None or cfg.critic_lr is None or cfg.target_tau is None:
            raise ValueError("PPOConfig must be resolved (algorithms.resolve_ppo) before use")
        self.actor, self.critic, self.cfg = actor, critic, cfg
        self.target_tau = cfg.target_tau
        self.target_critic = make_target(critic)
        self.actor_opt = torch.optim.Adam(actor.parameters(), lr=cfg.lr, eps=1e-5)
        self.critic_opt = torch.optim.Adam(critic.parameters(), lr=cfg.critic_lr, eps=1e-5)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.num_updates = 0
        self.next_critic_hidden: np.ndarray | None = None  # critic_h0 for the next rollout
        self.timings = {"critic": 0.0, "actor_update": 0.0}  # wall seconds (benchmark shares)

    def export_actor(self, version: int) -> ActorWeights:
        return self.actor.export(version)

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
        self.next_critic_hidden = carry.numpy().copy()
        return values, adv, value_targets(adv, values)

    def _actor_logits(self, r: dict[str, Tensor], envs: Tensor) -> Tensor:
        obs = self.actor.with_robot_id(r["obs"][:, envs])  # [T, b, N, in]
        t, b, n = obs.shape[:3]
        resets = r["resets"][:, envs, None].expand(t, b, n).reshape(t, b * n)
        h0 = r["actor_h0"][envs].reshape(b * n, -1)
        return self.actor.forward_sequence(obs.reshape(t, b * n, -1), h0, resets).reshape(
            t, b, n, -1)

    # -- the update -----------------------------------------------------------------------

    def update(self, rollout: Rollout) -> dict[str, float]:
        """One PPO update on a rollout; returns scalar metrics keyed by TensorBoard tag."""
        rollout.validate()
        cfg = self.cfg
        r = {
            "obs": torch.from_numpy(rollout.obs), "state": torch.from_numpy(rollout.state),
            "actions": torch.from_numpy(rollout.actions),
            "logp_old": torch.from_numpy(rollout.log_probs),
            "rewards": torch.from_numpy(rollout.rewards),
            "terminated": torch.from_numpy(rollout.terminated),
            "done": torch.from_numpy(rollout.done), "resets": torch.from_numpy(rollout.resets()),
            "final_obs": torch.from_numpy(rollout.final_obs),
            "final_state": torch.from_numpy(rollout.final_state),
            "actor_h0": torch.from_numpy(rollout.actor_h0),
        }
        b = rollout.shape[1]
        h0 = (torch.from_numpy(rollout.critic_h0) if rollout.critic_h0 is not None
              else self.critic.initial_state(b))
        t0 = time.perf_counter()
        values, adv, targets = self._targets(r, h0)
        self.timings["critic"] += time.perf_counter() - t0

        sums: dict[str, float] = {}
        count = 0
        num_mb = max(1, min(cfg.num_minibatches, b))
        for _epoch in range(cfg.epochs):
            perm = torch.from_numpy(self.rng.permutation(b))
            for envs in perm.chunk(num_mb):
                t0 = time.perf_counter()
                logits = self._actor_logits(r, envs)
                logp_all = torch.log_softmax(logits, dim=-1)
                logp = logp_all.gather(-1, r["actions"][:, envs, :, None]).squeeze(-1)
                entropy = -(logp_all.exp() * logp_all).sum(-1).mean()
                mb_adv = adv[:, envs]
                if cfg.normalize_advantages and mb_adv.numel() > 1:
                    mb_adv = (mb_adv - mb_adv.mean()) / (mb_adv.std() + 1e-8)
                pg_loss, approx_kl, clipfrac = clipped_policy_loss(
                    logp, r["logp_old"][:, envs], mb_adv, cfg.clip)
                actor_loss = pg_loss - cfg.entropy_coef * entropy
                t1 = time.perf_counter()

                out = self.critic.forward_sequence(r["obs"][:, envs], r["state"][:, envs],
                                                   h0[:, envs], r["resets"][:, envs])
                td_loss = ((out.values - targets[:, envs]) ** 2).mean()  # eq. loss
                critic_loss = td_loss + out.aux_loss  # eq. total_loss
                if not (torch.isfinite(actor_loss) and torch.isfinite(critic_loss)):
                    raise NonFiniteLossError(
                        f"non-finite loss in update {self.num_updates + 1}: actor "
                        f"{float(actor_loss)}, critic {float(critic_loss)}")

                t2 = time.perf_counter()
                self.actor_opt.zero_grad(set_to_none=True)
                actor_loss.backward()
                a_norm = nn.utils.clip_grad_norm_(self.actor.parameters(), cfg.max_grad_norm)
                self.actor_opt.step()
                t3 = time.perf_counter()
                self.critic_opt.zero_grad(set_to_none=True)
                critic_loss.backward()
                c_norm = nn.utils.clip_grad_norm_(self.critic.parameters(), cfg.max_grad_norm)
                self.critic_opt.step()
                soft_update(self.target_critic, self.critic, self.target_tau)
                t4 = time.perf_counter()
                self.timings["actor_update"] += (t1 - t0) + (t3 - t2)
                self.timings["critic"] += (t2 - t1) + (t4 - t3)

                step = {
                    "losses/policy_loss": pg_loss, "losses/value_loss": td_loss,
                    "losses/entropy": entropy, "losses/approx_kl": approx_kl,
                    "losses/clipfrac": clipfrac, "losses/actor_grad_norm": a_norm,
                    "losses/critic_grad_norm": c_norm, **out.metrics,
                }
                for k, v in step.items():
                    sums[k] = sums.get(k, 0.0) + float(v.detach())
                count += 1
        self.num_updates += 1
        metrics = {k: v / count for k, v in sums.items()}
        metrics["losses/explained_variance"] = explained_variance(values, targets)
        metrics["losses/advantage_mean"] = float(adv.mean())
        return metrics
