"""Baselines of the paper's comparison (Table "method comparison"), each behind the algorithm
interface of ``sdhn_train.algorithms``:

- ``dicg``: DICG critic (Li et al. 2021) for the shared PPO learner;
- ``qmix``: QMIX (Rashid et al. 2018): recurrent agent Q-nets, monotonic mixer, episode replay;
- ``hgcn_mix``: HGCN-MIX (Bai et al. 2021): QMIX's learner with a hypergraph-convolution mixer.

Select with ``train --algo qmix|dicg|hgcn_mix``.
"""
