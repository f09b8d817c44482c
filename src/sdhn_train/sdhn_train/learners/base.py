"""The one interface every learner implements, and what its methods exchange.

    learner = algorithm.build_learner(cfg, info, rng)    # sdhn_train.algorithms.registry
    actions, logp = learner.sample_actions(logits)        # the collector's action choice
    metrics = learner.update(rollout)                      # one update on a collected rollout
    arrays, meta = learner.state_dict()                    # every tensor + JSON-able meta
    learner.load_state_dict(arrays, meta)
    blob = learner.export_actor(version)                   # torch-free actor weights

Checkpoint slot names are shared by all learners: ``actor.*`` (the decentralised network),
``critic.*`` (PPO's critic, or the value-mixing learner's mixer), ``target.*`` (their target
copies), ``optim.actor.*``/``optim.critic.*``; a learner may add ``learner.*`` arrays and a
``learner`` meta entry of its own (the value-mixing learner's replay buffer).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt
import torch
from torch import Tensor

from sdhn_policy.actor_torch import Actor
from sdhn_policy.weights import ActorWeights
from sdhn_train.rollout import Rollout

F32 = npt.NDArray[np.float32]
Arrays = dict[str, np.ndarray]
JsonDict = dict[str, Any]  # what json.dumps writes: str keys, JSON values


class NonFiniteLossError(RuntimeError):
    """A loss became NaN/inf; training must stop."""


@dataclass
class HypergraphSamples:
    """Hypergraphs a critic generated over a rollout (SDHN only)."""

    p_h: F32  # [T, B, N, M] P_H
    incidence: npt.NDArray[np.uint8]  # [T, B, N, M] a sampled H
    skewness: F32  # [T, B] Sk of the sampled H


class Learner(Protocol):
    """What the trainers, the stream learner and the checkpoints use of a learner."""

    num_updates: int  # updates done (the in-process trainer's exported actor version)
    timings: dict[str, float]  # wall seconds per part ("critic", "actor_update"), for benchmarks

    @property
    def actor(self) -> Actor:
        """The decentralised network the robots run (PPO's policy, QMIX's agent net)."""
        ...

    def initial_critic_hidden(self, batch: int) -> F32:
        """The critic's hidden state before the first rollout of ``batch`` environments."""
        ...

    def next_critic_hidden(self) -> F32:
        """The critic's hidden state the next rollout starts from (after the last update)."""
        ...

    def sample_actions(self, logits: Tensor) -> tuple[Tensor, Tensor]:
        """Actions [X] for the actor's outputs [X, A] and their log-probs under the behaviour
        policy (torch's global RNG)."""
        ...

    def update(self, rollout: Rollout) -> dict[str, float]:
        """Learn from one rollout; scalar metrics keyed by TensorBoard tag."""
        ...

    def hidden_after(self, obs: F32, state: F32) -> tuple[F32, F32]:
        """(actor hidden [N, H], critic hidden) after running the current networks over an
        episode prefix obs [P, N, D], state [P, S] of one environment (P may be 0)."""
        ...

    def hypergraphs(self, rollout: Rollout) -> HypergraphSamples | None:
        """The critic's hypergraphs over ``rollout``, or None for critics without any."""
        ...

    def state_dict(self) -> tuple[Arrays, JsonDict]:
        ...

    def load_state_dict(self, arrays: Arrays, meta: JsonDict) -> None:
        ...

    def export_actor(self, version: int) -> ActorWeights:
        ...


def sample_categorical(logits: Tensor) -> tuple[Tensor, Tensor]:
    """Actions [X] ~ Categorical(logits [X, A]) and their log-probs [X]."""
    logp_all = torch.log_softmax(logits, -1)
    # Gumbel-max sampling == Categorical(logits).sample()
    a = (logp_all - torch.log(-torch.log(torch.rand_like(logp_all)))).argmax(-1)
    return a, logp_all.gather(-1, a[:, None])[:, 0]


@torch.no_grad()
def actor_hidden_after(actor: Actor, obs: F32) -> F32:
    """The actor's GRU state [N, H] after an episode prefix obs [P, N, D] (zeros if P = 0)."""
    dev = actor_device(actor)
    h = torch.zeros(obs.shape[1], actor.spec.gru_hidden, device=dev)
    if obs.shape[0]:
        x = actor.with_robot_id(torch.from_numpy(obs).to(dev))
        for t in range(obs.shape[0]):
            _, h = actor.step(x[t], h)
    return h.cpu().numpy().copy()


def actor_device(actor: Actor) -> torch.device:
    """Where the actor's parameters are (train.device)."""
    return next(actor.parameters()).device
