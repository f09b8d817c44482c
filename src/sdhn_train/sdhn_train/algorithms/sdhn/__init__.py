"""SDHN (Skewness-Driven Hypergraph Network): ``hypergraph`` (generator f_g, Binary Concrete
sampling, HGCN), ``skewness`` (gamma, Sk, L_Sk), ``critic`` (the centralised critic) and
``algorithm`` (its config section and learner)."""

from sdhn_train.algorithms.sdhn.algorithm import SDHN, SDHNConfig

__all__ = ["SDHN", "SDHNConfig"]
