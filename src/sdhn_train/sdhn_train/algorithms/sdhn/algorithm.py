"""SDHN: the shared actor, the stochastic-hypergraph HGCN critic with the skewness loss and a
target critic, on the PPO learner."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sdhn_train.algorithms.base import Settings, ppo_learner
from sdhn_train.algorithms.sdhn.critic import SDHNCritic
from sdhn_train.algorithms.sdhn.hypergraph import NOISES, Noise
from sdhn_train.envinfo import EnvInfo
from sdhn_train.learners.base import Learner
from sdhn_train.sections import need, need_positive, opt


@dataclass
class SDHNConfig:
    num_hyperedges: int = opt(10, "M: hyperedges in the generated hypergraph")
    generator_hidden: int = opt(64, "f_g GRU hidden size")
    generator_layers: int = opt(3, "f_g GRU layers (paper: 3)")
    hgcn_hidden: int = opt(64, "HGCN feature size")
    hgcn_layers: int = opt(2, "HGCN layers (paper: 2)")
    state_hidden: int = opt(64, "global-state encoder size of the value head")
    tau: float = opt(1.0, "Binary Concrete temperature")
    noise: str = opt("logistic", f"Binary Concrete noise, one of {', '.join(NOISES)}")
    lambda_sk: float = opt(-0.6, "target skewness lambda_Sk, in (-1, 1)")
    lambda_cb: float = opt(1.0, "weight lambda_CB of L_Sk in the critic loss, >= 0")
    skew_loss: bool = opt(True, "add lambda_CB * L_Sk (false = ablation 'w/o L_Sk')")
    stochastic_hyperedges: bool = opt(True, "sample H (false = ablation 'w/o SHR', H=1{P_H>=0.5})")

    def validate(self) -> None:
        need(self.noise in NOISES, "sdhn.noise", ", ".join(NOISES), self.noise)
        need_positive("sdhn", {
            "num_hyperedges": self.num_hyperedges, "generator_hidden": self.generator_hidden,
            "generator_layers": self.generator_layers, "hgcn_hidden": self.hgcn_hidden,
            "hgcn_layers": self.hgcn_layers, "state_hidden": self.state_hidden})
        need(-1.0 < self.lambda_sk < 1.0, "sdhn.lambda_sk", "(-1, 1) (the range of Sk)",
             self.lambda_sk)
        need(self.lambda_cb >= 0.0, "sdhn.lambda_cb", ">= 0", self.lambda_cb)
        need(self.tau > 0.0, "sdhn.tau", "> 0", self.tau)


class SDHN:
    name = "sdhn"
    config = SDHNConfig
    data_parallel = True
    default_lr = 6e-4
    default_target_tau = 0.01

    def build_learner(self, cfg: Settings, info: EnvInfo, rng: np.random.Generator) -> Learner:
        s = cfg.section(SDHNConfig)
        noise: Noise = "gumbel_paper" if s.noise == "gumbel_paper" else "logistic"
        critic = SDHNCritic(
            info.obs_size, info.state_size, info.num_robots, num_hyperedges=s.num_hyperedges,
            generator_hidden=s.generator_hidden, generator_layers=s.generator_layers,
            hgcn_hidden=s.hgcn_hidden, hgcn_layers=s.hgcn_layers, state_hidden=s.state_hidden,
            tau=s.tau, noise=noise, stochastic_hyperedges=s.stochastic_hyperedges,
            skew_loss=s.skew_loss, lambda_sk=s.lambda_sk, lambda_cb=s.lambda_cb)
        return ppo_learner(cfg, info, rng, critic, default_lr=self.default_lr,
                           default_target_tau=self.default_target_tau)
