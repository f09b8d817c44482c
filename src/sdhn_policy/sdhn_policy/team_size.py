"""An actor moved to another team size. MAIF's actor input does not depend on N; an actor that
reads a one-hot robot id (RWARE's EPyMARL settings) has N id inputs. Moving it keeps the weights
of the ids both teams have; a robot id the trained actor never saw starts from the mean of the
trained ids' weights (an "average robot"), and ids the new team lacks are dropped. The
observation part of the input is unchanged. NumPy only: used by warm start
(``sdhn_train.warm_start``) and by zero-shot evaluation on another team
(``scripts/eval_rware_policy.py``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from sdhn_policy.weights import ActorSpec, Tensors


def input_tensor_name(spec: ActorSpec) -> str:
    """The tensor whose columns are the actor's inputs: the first of ``ActorSpec.tensor_shapes``
    (encoder, else GRU, else head, in the order the input flows through them)."""
    return next(iter(spec.tensor_shapes()))


def resize_robot_ids(weight: npt.NDArray[np.float32], features: int,
                     num_robots: int) -> npt.NDArray[np.float32]:
    """[out, features + n] -> [out, features + num_robots]: observation columns unchanged, the
    first min(n, num_robots) id columns kept, new ones the mean of the trained ids'."""
    obs_part, ids = weight[:, :features], weight[:, features:]  # ids: >= 1 (ActorSpec.check)
    keep = ids[:, :num_robots]
    extra = np.repeat(ids.mean(axis=1, keepdims=True), num_robots - keep.shape[1], axis=1)
    return np.ascontiguousarray(np.concatenate([obs_part, keep, extra], axis=1),
                                dtype=np.float32)


def for_team(spec: ActorSpec, tensors: Tensors, num_robots: int) -> tuple[ActorSpec, Tensors]:
    """The actor ``(spec, tensors)`` for a team of ``num_robots`` (unchanged without robot ids)."""
    new = dataclasses.replace(spec, num_robots=num_robots)
    if not spec.use_robot_id or spec.num_robots == num_robots:
        return new, tensors
    name = input_tensor_name(spec)
    return new, {**tensors, name: resize_robot_ids(tensors[name], spec.feature_size,
                                                   num_robots)}
