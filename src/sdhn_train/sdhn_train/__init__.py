"""Centralised training: SDHN critic, PPO, baselines, in-process trainer and the trainer node."""
