"""Algorithms, one module each, listed once in ``registry.ALGORITHMS``:

- ``sdhn/``: SDHN, stochastic-hypergraph HGCN critic with the skewness loss (PPO learner);
- ``mappo``: MAPPO, MLP critic on the global state (PPO learner);
- ``dicg``: DICG critic (Li et al. 2021) (PPO learner);
- ``qmix``: QMIX (Rashid et al. 2018), monotonic hypernetwork mixer (value-mixing learner);
- ``hgcn_mix``: HGCN-MIX (Bai et al. 2021), hypergraph-convolution mixer (value-mixing learner).

Each module owns its config section (a dataclass with ``validate``) and builds a
``sdhn_train.learners.base.Learner``. How to add one: docs/adding-an-algorithm.md.
"""
