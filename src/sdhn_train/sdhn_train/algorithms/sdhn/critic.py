"""SDHN's centralised critic: a stochastic hypergraph over the robots, generated from their
observations, message passing by hypergraph convolution, and the skewness loss as its auxiliary
loss. Equations: docs/sdhn-equations.md.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor
from torch.nn import functional as F

from sdhn_train.algorithms.sdhn.hypergraph import HGCN, HypergraphGenerator, Noise, binary_concrete
from sdhn_train.algorithms.sdhn.skewness import (
    hyperedge_degrees,
    sample_skewness,
    skewness_loss,
    squashed_skewness,
)
from sdhn_train.learners.base import HypergraphSamples
from sdhn_train.learners.ppo import Critic, CriticOutput
from sdhn_train.nets import mlp


class SDHNCritic(Critic):
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
        self.hgcn_hidden = hgcn_hidden
        self.state_encoder = mlp([state_size, state_hidden])
        self.value_head = torch.nn.Sequential(mlp([state_hidden + hgcn_hidden, 64]),
                                              torch.nn.Linear(64, 1))

    def initial_state(self, batch: int) -> Tensor:
        return self.generator.initial_state(batch)

    def _values(self, logits: Tensor, obs: Tensor, state: Tensor) -> tuple[Tensor, Tensor]:
        """logits [..., N, M], obs [..., N, D], state [..., S] -> (values [..., N], H)."""
        incidence, _ = binary_concrete(logits, self.tau, self.noise, self.stochastic)
        lead = obs.shape[:-2]
        n = obs.shape[-2]
        x = self.node_encoder(obs).reshape(-1, n, self.hgcn_hidden)
        m = self.hgcn(x, incidence.reshape(-1, n, incidence.shape[-1])).reshape(*lead, n, -1)
        return self._head(self.state_encoder(state), m), incidence

    def _head(self, s: Tensor, m: Tensor) -> Tensor:
        """value_head([s, m_i]) for every robot i: s [..., S_h] (one per team), m [..., N, F].

        The first layer is split, W [s; m] + b = (W_s s + b) + W_m m_i, so the state's part is
        computed once per team instead of once per robot (no N-fold copy of s): the same
        arithmetic as the concatenation up to float rounding (test_hypergraph checks 1e-5)."""
        first = next(iter(self.value_head[0].children()))
        assert isinstance(first, torch.nn.Linear)
        k = s.shape[-1]
        pre = F.linear(s, first.weight[:, :k], first.bias).unsqueeze(-2) \
            + F.linear(m, first.weight[:, k:])
        return self.value_head[1](torch.relu(pre)).squeeze(-1)

    def forward_sequence(self, obs: Tensor, state: Tensor, h0: Tensor,
                         resets: Tensor) -> CriticOutput:
        logits, hiddens = self.generator.forward_sequence(obs, h0, resets)
        values, incidence = self._values(logits, obs, state)
        gamma = sample_skewness(hyperedge_degrees(incidence))  # [T, B]
        sk = squashed_skewness(gamma)
        l_sk = skewness_loss(sk, self.lambda_sk)
        aux = self.lambda_cb * l_sk if self.use_skew_loss else values.new_zeros(())
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
            obs[None], h, torch.zeros(1, obs.shape[0], dtype=torch.bool, device=obs.device))
        return self._values(logits[0], obs, state)[0]

    def hypergraphs(self, obs: Tensor, h0: Tensor, resets: Tensor) -> HypergraphSamples:
        """P_H, one sampled H and its Sk at every step (the ROS ``hypergraph`` topic, P_H
        snapshots)."""
        logits, _ = self.generator.forward_sequence(obs, h0, resets)
        incidence, _ = binary_concrete(logits, self.tau, self.noise, self.stochastic)
        sk = squashed_skewness(sample_skewness(hyperedge_degrees(incidence)))
        return HypergraphSamples(torch.sigmoid(logits).cpu().numpy().copy(),
                                 incidence.cpu().numpy().astype(np.uint8),
                                 sk.cpu().numpy().copy())
