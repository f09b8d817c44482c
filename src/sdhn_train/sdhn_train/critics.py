"""Centralised critics behind one interface: SDHN's hypergraph critic and MAPPO's MLP critic.

A critic maps a stored sequence (obs [T, B, N, D], state [T, B, S]) to per-robot values
[T, B, N]; it may be recurrent (``initial_state``/hidden carried across steps and rollouts) and may
add an auxiliary loss (SDHN's lambda_CB * L_Sk). Both are used by the one PPO learner.
"""

from __future__ import annotations

import copy
import itertools
from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from sdhn_train.hypergraph import HGCN, HypergraphGenerator, Noise, binary_concrete
from sdhn_train.skewness import (
    hyperedge_degrees,
    sample_skewness,
    skewness_loss,
    squashed_skewness,
)


@dataclass
class CriticOutput:
    values: Tensor  # [T, B, N]
    hiddens: Tensor  # [T, *hidden shape]: hidden *after* each step (for bootstrap values)
    aux_loss: Tensor  # scalar added to the TD loss (0 for critics without one)
    metrics: dict[str, Tensor] = field(default_factory=dict)  # detached scalars to log


def mlp(sizes: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for a, b in itertools.pairwise(sizes):
        layers += [nn.Linear(a, b), nn.ReLU()]
    return nn.Sequential(*layers)


class SDHNCritic(nn.Module):
    """V_i(s, o) = head([enc(s), m_i]) with m = HGCN(enc(o), H), H ~ BinaryConcrete(f_g(o, h))."""

    def __init__(self, obs_size: int, state_size: int, num_robots: int, *, num_hyperedges: int = 10,
                 generator_hidden: int = 64, generator_layers: int = 3, hgcn_hidden: int = 64,
                 hgcn_layers: int = 2, state_hidden: int = 64, tau: float = 1.0,
                 noise: Noise = "logistic", stochastic_hyperedges: bool = True,
                 skew_loss: bool = True, lambda_sk: float = -0.6, lambda_cb: float = 1.0) -> None:
        super().__init__()
        self.tau, self.noise, self.stochastic = tau, noise, stochastic_hyperedges
        self.use_skew_loss, self.lambda_sk, self.lambda_cb = skew_loss, lambda_sk, lambda_cb
        self.generator = HypergraphGenerator(obs_size, num_robots, num_hyperedges,
                                             generator_hidden, generator_layers)
        self.node_encoder = mlp([obs_size, hgcn_hidden])
        self.hgcn = HGCN(hgcn_hidden, hgcn_hidden, hgcn_layers)
        self.state_encoder = mlp([state_size, state_hidden])
        self.value_head = nn.Sequential(mlp([state_hidden + hgcn_hidden, 64]), nn.Linear(64, 1))

    def initial_state(self, batch: int) -> Tensor:
        return self.generator.initial_state(batch)

    def _values(self, logits: Tensor, obs: Tensor, state: Tensor) -> tuple[Tensor, Tensor]:
        """logits [..., N, M], obs [..., N, D], state [..., S] -> (values [..., N], H)."""
        incidence, _ = binary_concrete(logits, self.tau, self.noise, self.stochastic)
        lead = obs.shape[:-2]
        n = obs.shape[-2]
        x = self.node_encoder(obs).reshape(-1, n, self.hgcn.layers[0].theta.in_features)
        m = self.hgcn(x, incidence.reshape(-1, n, incidence.shape[-1])).reshape(*lead, n, -1)
        s = self.state_encoder(state).unsqueeze(-2).expand(*lead, n, -1)
        return self.value_head(torch.cat([s, m], dim=-1)).squeeze(-1), incidence

    def forward_sequence(self, obs: Tensor, state: Tensor, h0: Tensor,
                         resets: Tensor) -> CriticOutput:
        logits, hiddens = self.generator.forward_sequence(obs, h0, resets)
        values, incidence = self._values(logits, obs, state)
        gamma = sample_skewness(hyperedge_degrees(incidence))  # [T, B]
        sk = squashed_skewness(gamma)
        l_sk = skewness_loss(sk, self.lambda_sk)
        aux = self.lambda_cb * l_sk if self.use_skew_loss else torch.zeros((), dtype=values.dtype)
        metrics = {
            "losses/skew_loss": l_sk.detach(),
            "hypergraph/skewness": sk.detach().mean(),
            "hypergraph/gamma": gamma.detach().mean(),
            "hypergraph/mean_p": torch.sigmoid(logits.detach()).mean(),
            "hypergraph/mean_edge_size": hyperedge_degrees(incidence.detach()).mean(),
        }
        return CriticOutput(values, hiddens, aux, metrics)

    def value_step(self, obs: Tensor, state: Tensor, h: Tensor) -> Tensor:
        """One more step from hidden h [L, K, Hg]: obs [K, N, D], state [K, S] -> values [K, N]."""
        logits, _ = self.generator.forward_sequence(
            obs[None], h, torch.zeros(1, obs.shape[0], dtype=torch.bool))
        return self._values(logits[0], obs, state)[0]

    def probabilities(self, obs: Tensor, h0: Tensor, resets: Tensor) -> Tensor:
        """P_H [T, B, N, M] (for heatmaps and the ROS ``hypergraph`` topic)."""
        return torch.sigmoid(self.generator.forward_sequence(obs, h0, resets)[0])


class MLPCritic(nn.Module):
    """MAPPO's centralised critic: V(s) from the global state, shared by all N robots."""

    def __init__(self, state_size: int, num_robots: int, hidden: tuple[int, ...] = (64, 64)):
        super().__init__()
        self.num_robots = num_robots
        self.net = nn.Sequential(mlp([state_size, *hidden]), nn.Linear(hidden[-1], 1))

    def initial_state(self, batch: int) -> Tensor:
        return torch.zeros(0, batch, 0)

    def forward_sequence(self, obs: Tensor, state: Tensor, h0: Tensor,
                         resets: Tensor) -> CriticOutput:
        values = self.net(state).expand(*state.shape[:-1], self.num_robots)
        hiddens = h0.unsqueeze(0).expand(state.shape[0], *h0.shape)
        return CriticOutput(values, hiddens, torch.zeros((), dtype=values.dtype))

    def value_step(self, obs: Tensor, state: Tensor, h: Tensor) -> Tensor:
        return self.net(state).expand(*state.shape[:-1], self.num_robots)


Critic = SDHNCritic | MLPCritic


def soft_update(target: nn.Module, source: nn.Module, rate: float) -> None:
    """theta' <- (1 - rate) theta' + rate theta (target critic of eq. v_target / td_error)."""
    with torch.no_grad():
        for tp, sp in zip(target.parameters(), source.parameters(), strict=True):
            tp.lerp_(sp, rate)


def make_target(critic: nn.Module) -> nn.Module:
    target = copy.deepcopy(critic)
    target.requires_grad_(False)
    return target
