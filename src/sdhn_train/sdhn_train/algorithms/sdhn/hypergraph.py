"""Stochastic hypergraph: generator f_g, Binary Concrete sampling, and the HGCN layer.

Equation names are the paper's labels; docs/sdhn-equations.md maps each to this code and records
the decisions where the paper is silent or contradicts itself.
Shapes: X = any batch, N robots, M hyperedges, F features.
"""

from __future__ import annotations

import itertools
from typing import Literal, get_args

import torch
from torch import Tensor, nn

from sdhn_policy.actor_torch import SequenceFn, gru_sequence

Noise = Literal["logistic", "gumbel_paper"]
NOISES: tuple[str, ...] = get_args(Noise)  # the one list of Binary Concrete noise laws


class HypergraphGenerator(nn.Module):
    """f_g (eq. Hypergraph_generator): P_H = f_g({o_i^t}, h^{t-1}).

    Decision: the group's latent state comes from one GRU over the concatenation of all robots'
    observations (so every row of P_H sees the whole group), ``num_layers`` deep (paper: 3), with
    the hidden state carried across time steps; a linear layer maps it to N x M logits.
    """

    def __init__(self, obs_size: int, num_robots: int, num_hyperedges: int, hidden: int = 64,
                 num_layers: int = 3) -> None:
        super().__init__()
        self.num_robots, self.num_hyperedges = num_robots, num_hyperedges
        self.num_layers, self.hidden = num_layers, hidden
        self.encoder = nn.Sequential(nn.Linear(obs_size * num_robots, hidden), nn.ReLU())
        self.gru = nn.GRU(hidden, hidden, num_layers=num_layers)
        self.gru_sequence: SequenceFn = gru_sequence  # swappable like Actor.gru_sequence
        self.to_logits = nn.Linear(hidden, num_robots * num_hyperedges)

    def initial_state(self, batch: int) -> Tensor:
        return torch.zeros(self.num_layers, batch, self.hidden)

    def forward_sequence(self, obs: Tensor, h0: Tensor, resets: Tensor) -> tuple[Tensor, Tensor]:
        """obs [T, B, N, D], h0 [L, B, Hg], resets [T, B] -> (logits [T, B, N, M], hiddens
        [T, L, B, Hg]: the hidden state after step t, valid at the last step and at steps
        followed by a reset -- see ``gru_sequence``).

        Where resets[t], the hidden state is zeroed before step t (a new episode starts)."""
        t_len, b = obs.shape[:2]
        x = self.encoder(obs.reshape(t_len, b, -1))
        out, hiddens = self.gru_sequence(self.gru, x, h0, resets)
        logits = self.to_logits(out)
        return logits.reshape(t_len, b, self.num_robots, self.num_hyperedges), hiddens


class _StraightThroughStep(torch.autograd.Function):
    """Forward 1{y >= 0.5} (exactly 0/1, unlike ``hard + y - y.detach()`` which rounds to
    0.99999994); backward passes the gradient of y through unchanged."""

    @staticmethod
    def forward(ctx: object, y: Tensor) -> Tensor:
        return (y >= 0.5).to(y.dtype)

    @staticmethod
    def backward(ctx: object, grad: Tensor) -> Tensor:
        return grad


def binary_concrete(logits: Tensor, tau: float, noise: Noise = "logistic",
                    stochastic: bool = True) -> tuple[Tensor, Tensor]:
    """Binary Concrete relaxation with a straight-through hard sample (unlabelled eq. for y).

    y = sigmoid((log p - log(1-p) + eps) / tau) with log p - log(1-p) = ``logits``;
    H = 1{y >= 0.5} forward, gradient of y backward (straight-through, as ``H_hard + y -
    y.detach()`` but exactly 0/1).
    ``noise="logistic"``: eps = log u - log(1-u), which gives P(H=1) = p exactly (our decision,
    docs/sdhn-equations.md).
    ``noise="gumbel_paper"``: eps = log(-log u), the paper's single-Gumbel form.
    ``stochastic=False`` (ablation "w/o SHR"): eps = 0, i.e. H = 1{P_H >= 0.5}.
    Returns (H [straight-through], y).
    """
    if stochastic:
        u = torch.rand_like(logits).clamp_(1e-7, 1.0 - 1e-7)
        if noise == "logistic":
            eps = torch.log(u) - torch.log1p(-u)
        elif noise == "gumbel_paper":
            eps = torch.log(-torch.log(u))
        else:
            raise ValueError(f"noise must be one of {NOISES}, got {noise!r}")
        y = torch.sigmoid((logits + eps) / tau)
    else:
        y = torch.sigmoid(logits / tau)
    return _StraightThroughStep.apply(y), y


def safe_inverse_power(deg: Tensor, power: float) -> Tensor:
    """deg**(-power) where deg > 0 and exactly 0 where deg == 0 (pseudo-inverse, no epsilon);
    the gradient is finite everywhere."""
    pos = deg > 0
    return torch.where(pos, torch.where(pos, deg, torch.ones_like(deg)).pow(-power),
                       torch.zeros_like(deg))


def hgcn_propagate(x: Tensor, incidence: Tensor) -> Tensor:
    """D^-1/2 H B^-1 H^T D^-1/2 X (eq. HGCN without Theta and ReLU).

    x [X, N, F], incidence H [X, N, M]. d_i = sum_j H_ij, b_j = sum_i H_ij; a zero degree
    contributes 0. Computed as two thin products (never an N x N matrix)."""
    d_inv_sqrt = safe_inverse_power(incidence.sum(-1), 0.5).unsqueeze(-1)  # [X, N, 1]
    b_inv = safe_inverse_power(incidence.sum(-2), 1.0).unsqueeze(-1)  # [X, M, 1]
    edge = b_inv * (incidence.transpose(-1, -2) @ (d_inv_sqrt * x))  # [X, M, F]
    return d_inv_sqrt * (incidence @ edge)


class HGCNLayer(nn.Module):
    """One HGCN layer (eq. HGCN): X' = ReLU(D^-1/2 H B^-1 H^T D^-1/2 X Theta)."""

    def __init__(self, in_features: int, out_features: int) -> None:
        super().__init__()
        self.theta = nn.Linear(in_features, out_features, bias=False)

    def forward(self, x: Tensor, incidence: Tensor) -> Tensor:
        return torch.relu(hgcn_propagate(self.theta(x), incidence))


class HGCN(nn.Module):
    """Stack of HGCN layers (paper: 2); output m_i per robot."""

    def __init__(self, in_features: int, hidden: int, num_layers: int = 2) -> None:
        super().__init__()
        sizes = [in_features] + [hidden] * num_layers
        self.layers = nn.ModuleList(HGCNLayer(a, b) for a, b in itertools.pairwise(sizes))

    def forward(self, x: Tensor, incidence: Tensor) -> Tensor:
        for layer in self.layers:
            x = layer(x, incidence)
        return x
