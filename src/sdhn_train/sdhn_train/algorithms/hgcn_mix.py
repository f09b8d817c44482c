"""HGCN-MIX: Bai, Y., Gong, C., Zhang, B., Fan, G., Hou, X., Lu, Y., "Value Function
Factorization with Hypergraph Convolution for Cooperative Multi-agent Reinforcement Learning",
2021 (arXiv:2112.06771).

Value mixing with hypergraph convolution over the agents, on QMIX's learner (episode replay,
target networks, epsilon-greedy; ``qmix.*`` fields apply):
1. a *deterministic* learned hypergraph: incidence weights H = |Linear(enc(o_i))| in [0, inf)^{N x
   M} from each robot's observation (no sampling, no threshold, no skewness prior - the contrast
   to SDHN of the paper's Table "method comparison");
2. ``hgcn_layers`` rounds of hypergraph convolution (the shared ``hgcn_propagate``,
   D^-1/2 H B^-1 H^T D^-1/2, of ``sdhn_train.algorithms.sdhn.hypergraph``) over the agents'
   utilities, q^{l+1} = |theta_l| P q^l, added to q (P and |theta| are non-negative, so this keeps
   monotonicity: dQ_tot/dQ_i >= 0);
3. QMIX's monotonic hypernetwork mixer on the convolved utilities and the global state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from sdhn_train.algorithms.base import Settings
from sdhn_train.algorithms.qmix import QMIXConfig, QMixer, value_mixing_learner
from sdhn_train.algorithms.sdhn.hypergraph import hgcn_propagate
from sdhn_train.envinfo import EnvInfo
from sdhn_train.learners.base import Learner
from sdhn_train.learners.value_mixing import Mixer
from sdhn_train.nets import mlp
from sdhn_train.sections import need_positive, opt


@dataclass
class HGCNMixConfig:
    num_hyperedges: int = opt(10, "M: hyperedges of the learned deterministic hypergraph")
    hgcn_hidden: int = opt(64, "HGCN feature size")
    hgcn_layers: int = opt(2, "HGCN layers")

    def validate(self) -> None:
        need_positive("hgcn_mix", {"num_hyperedges": self.num_hyperedges,
                                   "hgcn_hidden": self.hgcn_hidden,
                                   "hgcn_layers": self.hgcn_layers})


class HGCNMixer(Mixer):
    def __init__(self, obs_size: int, state_size: int, num_robots: int, *,
                 num_hyperedges: int = 10, hgcn_hidden: int = 64, hgcn_layers: int = 2,
                 embed: int = 32, hypernet_hidden: int = 64) -> None:
        super().__init__()
        self.num_robots, self.num_hyperedges = num_robots, num_hyperedges
        self.edge_net = nn.Sequential(mlp([obs_size, hgcn_hidden]),
                                      nn.Linear(hgcn_hidden, num_hyperedges))
        self.theta = nn.Parameter(torch.full((hgcn_layers,), 0.5))
        self.qmix = QMixer(state_size, num_robots, embed, hypernet_hidden)

    def incidence(self, obs: Tensor) -> Tensor:
        """Deterministic weighted incidence H [..., N, M] >= 0 from observations [..., N, D]."""
        return self.edge_net(obs).abs()

    def forward(self, q: Tensor, obs: Tensor, state: Tensor) -> Tensor:
        lead, n = q.shape[:-1], q.shape[-1]
        h = self.incidence(obs).reshape(-1, n, self.num_hyperedges)
        x = q.reshape(-1, n, 1)
        out = x
        for theta in self.theta:
            x = theta.abs() * hgcn_propagate(x, h)
            out = out + x
        return self.qmix(out.reshape(*lead, n), obs, state)


class HGCNMIX:
    """HGCN-MIX (Bai et al. 2021): deterministic learned hypergraph, hypergraph convolution in a
    monotonic value mixer; QMIX's learner and ``qmix`` settings."""

    name = "hgcn_mix"
    config = HGCNMixConfig
    data_parallel = False
    default_lr = 5e-4

    def build_learner(self, cfg: Settings, info: EnvInfo, rng: np.random.Generator) -> Learner:
        h, q = cfg.section(HGCNMixConfig), cfg.section(QMIXConfig)
        mixer = HGCNMixer(info.obs_size, info.state_size, info.num_robots,
                          num_hyperedges=h.num_hyperedges, hgcn_hidden=h.hgcn_hidden,
                          hgcn_layers=h.hgcn_layers, embed=q.mixer_embed,
                          hypernet_hidden=q.hypernet_hidden)
        return value_mixing_learner(cfg, info, rng, mixer, self.default_lr)
