"""Warm start (``actor.init_from``): begin training from an exported actor, e.g. one trained on a
smaller team. MAIF's observation (57 floats) and its features do not depend on the team size, so
an actor trained alone on maif-solo or on maif-tiny runs unchanged on maif-10/16/20; the critic,
whose input does depend on N, starts fresh. An actor with one-hot robot ids is moved to the new
team size by ``sdhn_policy.team_size.for_team`` (ids both teams have keep their weights, new ones
start as the trained ids' mean).
"""

from __future__ import annotations

import dataclasses
import os

import torch

from sdhn_policy.actor_torch import Actor
from sdhn_policy.team_size import for_team
from sdhn_policy.weights import WeightsError, decode_weights, load_actor_file
from sdhn_train.config import ConfigError


def load_actor_into(actor: Actor, path: str | os.PathLike[str], temperature: float = 1.0) -> int:
    """Copy the weights of the actor file at ``path`` into ``actor``; returns their version.
    ConfigError when the file cannot be read or its network differs from ``actor``'s.

    ``temperature`` (``actor.init_temperature``) scales the output layer by 1/T, so the started
    policy is softmax(logits / T): the same greedy action everywhere, a higher entropy for T > 1.
    A warm actor trained elsewhere starts nearly deterministic, and on a task where its habits
    earn nothing its entropy bonus alone may never lift it (rware-3 from the tiny-2ag actor)."""
    try:
        blob = load_actor_file(path)
        spec, tensors = decode_weights(blob)
    except WeightsError as e:
        raise ConfigError(f"actor.init_from = {str(path)!r}: {e.reason}") from e
    mine = actor.spec
    # the team size only matters to a one-hot robot id, and for_team resizes that one
    if dataclasses.replace(spec, num_robots=mine.num_robots) != mine:
        raise ConfigError(f"actor.init_from = {str(path)!r}: its actor {spec} differs from the "
                          f"one configured here {mine}")
    _, tensors = for_team(spec, tensors, mine.num_robots)
    with torch.no_grad():
        for name, t in actor.tensors().items():
            t.copy_(torch.from_numpy(tensors[name]))
        if temperature != 1.0:
            actor.head.weight.div_(temperature)
            actor.head.bias.div_(temperature)
    return blob.version
