"""The deployable actor of any checkpoint (not only the one a finished run exported).

    blob, step = actor_from_checkpoint("runs/<run>/checkpoints/step_000001200128")
    save_actor_file("models/x/actor.safetensors", blob)

The checkpoint's own config rebuilds the actor's architecture and input features, its ``actor.*``
tensors fill it, and the version is the learner's update count, as the trainer would export it.
"""

from __future__ import annotations

from pathlib import Path

from sdhn_policy.actor_torch import Actor
from sdhn_policy.weights import ActorWeights
from sdhn_sim.envs import make_env
from sdhn_train import checkpoint as ckpt
from sdhn_train.config import Config, apply_dict
from sdhn_train.env_features import resolve_features, wrap_features
from sdhn_train.envinfo import EnvInfo, actor_spec


def actor_from_checkpoint(path: str | Path) -> tuple[ActorWeights, int]:
    """(exported actor, team env-steps of the checkpoint); CheckpointError if unreadable."""
    arrays, meta = ckpt.load_checkpoint(path)
    cfg = Config()
    apply_dict(cfg, meta["config"])
    env = make_env(cfg.env.name, num_envs=1, seed=0)  # sizes only
    actor = Actor(actor_spec(cfg.actor, EnvInfo.of(wrap_features(env, resolve_features(cfg)))))
    ckpt.load_module("actor", actor, arrays)
    return actor.export(int(meta.get("num_updates", 0))), int(meta["global_step"])
