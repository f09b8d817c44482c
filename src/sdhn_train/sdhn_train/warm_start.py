"""Warm start (``actor.init_from``): begin training from an exported actor, e.g. one trained on a
smaller team. MAIF's observation (57 floats) and its features do not depend on the team size, so
an actor trained alone on maif-solo or on maif-tiny runs unchanged on maif-10/16/20; the critic,
whose input does depend on N, starts fresh.

An actor that reads a one-hot robot id (RWARE's EPyMARL settings) has N id inputs. Moving it to
another team size keeps the weights of the ids both teams have; a robot id the trained actor
never saw starts from the mean of the trained ids' weights (an "average robot"), and ids the new
team lacks are dropped. The observation part of the input is copied unchanged.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import numpy.typing as npt
import torch

from sdhn_policy.actor_torch import Actor
from sdhn_policy.weights import WeightsError, decode_weights, load_actor_file
from sdhn_train.config import ConfigError


def load_actor_into(actor: Actor, path: str | os.PathLike[str]) -> int:
    """Copy the weights of the actor file at ``path`` into ``actor``; returns their version.
    ConfigError when the file cannot be read or its network differs from ``actor``'s."""
    try:
        blob = load_actor_file(path)
        spec, tensors = decode_weights(blob)
    except WeightsError as e:
        raise ConfigError(f"actor.init_from = {str(path)!r}: {e.reason}") from e
    mine = actor.spec
    trained_ids = spec.num_robots
    # the team size only matters to a one-hot robot id, and that one is resized below
    spec = dataclasses.replace(spec, num_robots=mine.num_robots)
    if spec != mine:
        raise ConfigError(f"actor.init_from = {str(path)!r}: its actor {spec} differs from the "
                          f"one configured here {mine}")
    if mine.use_robot_id and trained_ids != mine.num_robots:
        name = input_weight_name(actor)
        tensors = {**tensors, name: resize_robot_ids(tensors[name], mine.feature_size,
                                                     mine.num_robots)}
    with torch.no_grad():
        for name, t in actor.tensors().items():
            t.copy_(torch.from_numpy(tensors[name]))
    return blob.version


def input_weight_name(actor: Actor) -> str:
    """The tensor whose columns are the actor's inputs: the first of ``ActorSpec.tensor_shapes``
    (encoder, else GRU, else head, in the order the input flows through them)."""
    return next(iter(actor.spec.tensor_shapes()))


def resize_robot_ids(weight: npt.NDArray[np.float32], features: int,
                     num_robots: int) -> npt.NDArray[np.float32]:
    """[out, features + n] -> [out, features + num_robots]: observation columns unchanged, the
    first min(n, num_robots) id columns kept, new ones the mean of the trained ids'."""
    obs_part, ids = weight[:, :features], weight[:, features:]  # ids: >= 1 (ActorSpec.check)
    keep = ids[:, :num_robots]
    extra = np.repeat(ids.mean(axis=1, keepdims=True), num_robots - keep.shape[1], axis=1)
    return np.ascontiguousarray(np.concatenate([obs_part, keep, extra], axis=1),
                                dtype=np.float32)
