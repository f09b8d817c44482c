"""Learners behind one protocol (``sdhn_train.learners.base.Learner``):

- ``ppo.PPOLearner``: the one PPO update, with a pluggable centralised critic (SDHN, MAPPO,
  DICG);
- ``value_mixing.ValueMixingLearner``: off-policy value mixing with episode replay (QMIX,
  HGCN-MIX), with a pluggable mixer.

Algorithms (``sdhn_train.algorithms``) build one of them; the in-process trainer, the ROS
trainer node's stream learner and the checkpoints only use the protocol.
"""
