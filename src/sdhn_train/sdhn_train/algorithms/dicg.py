"""DICG critic: Li, S., Gupta, J.K., Morales, P., Allen, R., Kochenderfer, M.J., "Deep Implicit
Coordination Graphs for Multi-agent Reinforcement Learning", AAMAS 2021.

DICG-CE in actor-critic form: the actor is the shared decentralised actor (unchanged), trained by
the shared PPO learner; only the centralised critic differs. The critic
1. embeds each robot's observation, e_i = MLP(o_i);
2. learns a soft, fully connected coordination graph by attention, mu_ij = softmax_j(e_i^T W e_j)
   (the "implicit" graph: no edges are sampled or thresholded);
3. passes messages with ``gcn_layers`` GCN rounds, E^{l+1} = ReLU(mu E^l Theta^l), and keeps a
   residual, m_i = e_i + E^L_i (as in the DICG paper);
4. outputs per-robot values V_i = head([enc(s), m_i]) - the same value head as SDHN's critic, so
   the comparison differs only in the coordination structure (simple soft graph vs hypergraph).
It is feed-forward (no hidden state), so it plugs into ``PPOLearner`` like MAPPO's MLP critic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from sdhn_train.algorithms.base import Settings, ppo_learner
from sdhn_train.envinfo import EnvInfo
from sdhn_train.learners.base import Learner
from sdhn_train.learners.ppo import Critic, CriticOutput
from sdhn_train.nets import mlp
from sdhn_train.sections import need_positive, opt


@dataclass
class DICGConfig:
    embed: int = opt(64, "agent embedding size (attention and GCN width)")
    gcn_layers: int = opt(2, "GCN message-passing rounds over the soft adjacency")
    state_hidden: int = opt(64, "global-state encoder size of the value head")

    def validate(self) -> None:
        need_positive("dicg", {"embed": self.embed, "gcn_layers": self.gcn_layers,
                               "state_hidden": self.state_hidden})


class DICGCritic(Critic):
    def __init__(self, obs_size: int, state_size: int, num_robots: int, *, embed: int = 64,
                 gcn_layers: int = 2, state_hidden: int = 64) -> None:
        super().__init__()
        self.num_robots = num_robots
        self.encoder = mlp([obs_size, embed, embed])
        self.attention = nn.Linear(embed, embed, bias=False)  # W of e_i^T W e_j
        self.gcn = nn.ModuleList(nn.Linear(embed, embed, bias=False) for _ in range(gcn_layers))
        self.state_encoder = mlp([state_size, state_hidden])
        self.value_head = nn.Sequential(mlp([state_hidden + embed, 64]), nn.Linear(64, 1))

    def adjacency(self, e: Tensor) -> Tensor:
        """Soft adjacency mu [..., N, N] (rows sum to 1) from embeddings e [..., N, F]."""
        scores = self.attention(e) @ e.transpose(-1, -2) / math.sqrt(e.shape[-1])
        return torch.softmax(scores, dim=-1)

    def _values(self, obs: Tensor, state: Tensor) -> tuple[Tensor, Tensor]:
        e = self.encoder(obs)
        adj = self.adjacency(e)
        x = e
        for layer in self.gcn:
            x = torch.relu(adj @ layer(x))
        m = e + x
        s = self.state_encoder(state).unsqueeze(-2).expand(*m.shape[:-1], -1)
        return self.value_head(torch.cat([s, m], dim=-1)).squeeze(-1), adj

    def forward_sequence(self, obs: Tensor, state: Tensor, h0: Tensor,
                         resets: Tensor) -> CriticOutput:
        values, adj = self._values(obs, state)
        hiddens = h0.unsqueeze(0).expand(state.shape[0], *h0.shape)
        # Attention entropy per row (log N = uniform graph, 0 = one neighbour): a graph summary.
        entropy = -(adj * adj.clamp_min(1e-12).log()).sum(-1).mean()
        metrics = {"graph/attention_entropy": entropy.detach()}
        return CriticOutput(values, hiddens, values.new_zeros(()), metrics)

    def value_step(self, obs: Tensor, state: Tensor, h: Tensor) -> Tensor:
        return self._values(obs, state)[0]


class DICG:
    """DICG-CE (Li et al. 2021) as a PPO critic: MAPPO's learner, DICG's centralised critic."""

    name = "dicg"
    config = DICGConfig
    data_parallel = True
    default_lr = 3e-4
    default_target_tau = 1.0

    def build_learner(self, cfg: Settings, info: EnvInfo, rng: np.random.Generator) -> Learner:
        d = cfg.section(DICGConfig)
        critic = DICGCritic(info.obs_size, info.state_size, info.num_robots, embed=d.embed,
                            gcn_layers=d.gcn_layers, state_hidden=d.state_hidden)
        return ppo_learner(cfg, info, rng, critic, default_lr=self.default_lr,
                           default_target_tau=self.default_target_tau)
