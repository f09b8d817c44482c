"""Vectorised rollout collection and greedy evaluation for the in-process trainer.

The ROS trainer node does not collect: it assembles the same ``Rollout`` from messages
(``sdhn_train.transitions``)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from sdhn_policy.actor_torch import Actor
from sdhn_sim.envs.api import BatchedEnv, EpisodeStats
from sdhn_train.device import to_device
from sdhn_train.learners.base import actor_device, sample_categorical
from sdhn_train.rollout import Rollout


@dataclass
class Timings:
    """Wall seconds spent per part of the loop (for the benchmark and steps/s)."""

    env: float = 0.0
    actor: float = 0.0
    update: float = 0.0
    extra: dict[str, float] = field(default_factory=dict)


Sampler = Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]


class RolloutCollector:
    """Steps B environments with the shared actor and fills ``Rollout``s of length T.

    Keeps the environments' current obs/state and the actor's hidden state between rollouts.
    Actions are sampled with torch's global RNG (seeded in one place by the trainer), by
    ``sampler`` (default: from the policy's softmax; the trainer passes the learner's
    ``sample_actions``, epsilon-greedy for the value-mixing learner)."""

    def __init__(self, env: BatchedEnv, actor: Actor, rollout_len: int,
                 sampler: Sampler | None = None) -> None:
        self.env, self.actor, self.rollout_len = env, actor, rollout_len
        self.sample = sampler or sample_categorical
        b, n = env.num_envs, env.num_robots
        self.obs, self.state = env.reset()
        self.actor_h = np.zeros((b, n, actor.spec.gru_hidden), dtype=np.float32)
        self.timings = Timings()

    @torch.no_grad()
    def collect(self, critic_h0: np.ndarray | None) -> tuple[Rollout, list[EpisodeStats]]:
        env, t_len = self.env, self.rollout_len
        b, n, d = env.num_envs, env.num_robots, env.obs_size
        obs = np.empty((t_len, b, n, d), np.float32)
        state = np.empty((t_len, b, env.state_size), np.float32)
        final_obs = np.empty_like(obs)
        final_state = np.empty_like(state)
        actions = np.empty((t_len, b, n), np.int64)
        logps = np.empty((t_len, b, n), np.float32)
        rewards = np.empty((t_len, b), np.float32)
        term = np.empty((t_len, b), bool)
        trunc = np.empty((t_len, b), bool)
        actor_h0 = self.actor_h.copy()
        episodes: list[EpisodeStats] = []
        dev = actor_device(self.actor)
        h = to_device(self.actor_h, dev).reshape(b * n, -1)
        for t in range(t_len):
            t0 = time.perf_counter()
            obs[t], state[t] = self.obs, self.state
            x = self.actor.with_robot_id(to_device(self.obs, dev)).reshape(b * n, -1)
            logits, h = self.actor.step(x, h)
            a, logp = self.sample(logits)
            actions[t] = a.reshape(b, n).cpu().numpy()
            logps[t] = logp.reshape(b, n).cpu().numpy()
            t1 = time.perf_counter()
            res = env.step(actions[t])
            t2 = time.perf_counter()
            self.timings.actor += t1 - t0
            self.timings.env += t2 - t1
            rewards[t], term[t], trunc[t] = res.reward, res.terminated, res.truncated
            final_obs[t], final_state[t] = res.final_obs, res.final_state
            self.obs, self.state = res.obs, res.state
            done = res.terminated | res.truncated
            if done.any():
                h = h.reshape(b, n, -1)
                h[to_device(done, dev)] = 0.0
                h = h.reshape(b * n, -1)
            episodes.extend(res.episodes)
        self.actor_h = h.reshape(b, n, -1).cpu().numpy().copy()
        rollout = Rollout(obs, state, actions, logps, rewards, term, trunc, final_obs, final_state,
                          actor_h0, critic_h0)
        return rollout, episodes


@torch.no_grad()
def evaluate_greedy(env: BatchedEnv, actor: Actor, seed: int) -> list[EpisodeStats]:
    """One greedy episode in each of the B environments, from ``env.reset(seed)`` (fixed
    instances for a fixed seed). Returns the first finished episode of every environment."""
    obs, _ = env.reset(seed=seed)
    b, n = env.num_envs, env.num_robots
    dev = actor_device(actor)
    h = torch.zeros(b * n, actor.spec.gru_hidden, device=dev)
    first: dict[int, EpisodeStats] = {}
    for _ in range(env.max_steps):
        x = actor.with_robot_id(to_device(obs, dev)).reshape(b * n, -1)
        logits, h = actor.step(x, h)
        res = env.step(logits.argmax(-1).reshape(b, n).cpu().numpy())
        for ep in res.episodes:
            first.setdefault(ep.env_index, ep)
        if len(first) == b:
            break
        done = to_device(res.terminated | res.truncated, dev)
        h = h.reshape(b, n, -1)
        h[done] = 0.0
        h = h.reshape(b * n, -1)
        obs = res.obs
    return [first[k] for k in sorted(first)]
