"""Torch-free actor inference: MLP encoder -> GRU cell -> categorical logits, in NumPy.

This module runs inside every actor process and must never import torch. It computes exactly what
``sdhn_policy.actor_torch.Actor`` computes (tested to 1e-5)::

    rt = ActorRuntime.from_bytes(msg.format, msg.version, msg.payload, msg.sha256)
    h = rt.initial_state(1)
    action, log_prob, h = rt.act(obs[None], h, greedy=False, rng=rng, robot_id=i)

Shapes: ``obs`` [X, D] (X = any batch of robots), ``hidden`` [X, H]; ``robot_id`` an int or [X]
ints, required when the actor was trained with a one-hot robot id. ``obs`` is the raw observation
the environment sends: the runtime applies the spec's feature transform (``sdhn_policy.features``)
itself, so callers never need to know which features the actor was trained on.
"""

from __future__ import annotations

import os

import numpy as np
import numpy.typing as npt

from sdhn_policy.features import get_transform
from sdhn_policy.weights import (
    ActorSpec,
    ActorWeights,
    Tensors,
    decode_actor,
    load_actor_file,
)

F32 = npt.NDArray[np.float32]


def _sigmoid(x: F32) -> F32:
    return np.asarray(0.5 * (1.0 + np.tanh(0.5 * x)), dtype=np.float32)


def log_softmax(logits: F32) -> F32:
    z = logits - logits.max(axis=-1, keepdims=True)
    return np.asarray(z - np.log(np.exp(z).sum(axis=-1, keepdims=True)), dtype=np.float32)


def check_temperature(temperature: float) -> float:
    """``temperature`` if it is a usable sampling temperature (finite, > 0); ValueError else."""
    t = float(temperature)
    if not np.isfinite(t) or t <= 0.0:
        raise ValueError(f"temperature must be a finite number > 0, got {temperature!r}")
    return t


def choose_actions(logp: npt.NDArray[np.floating], greedy: bool, rng: np.random.Generator,
                   temperature: float = 1.0) -> npt.NDArray[np.int64]:
    """Actions [X] from log-probabilities [X, A]: the argmax (``greedy``), else one draw per row
    from softmax(logp / temperature) by inverse CDF with one uniform per row, so one seed gives
    one episode whatever computed ``logp`` (NumPy, ONNX or torch). A temperature below 1 sharpens
    the policy towards greedy play while keeping some randomness to leave a standstill."""
    if greedy:
        return np.asarray(logp.argmax(axis=-1), dtype=np.int64)
    lp = logp.astype(np.float64)
    t = check_temperature(temperature)
    if t != 1.0:  # renormalised in float64; t = 1 keeps the exact draws of earlier releases
        lp = lp / t
        lp = lp - lp.max(axis=-1, keepdims=True)
    cdf = np.cumsum(np.exp(lp), axis=-1)
    u = rng.random(len(cdf))[:, None] * cdf[:, -1:]
    return np.asarray(np.minimum((cdf < u).sum(axis=-1), logp.shape[1] - 1), dtype=np.int64)


class PolicyOutputError(ValueError):
    """A forward pass whose outputs break the actor's contract (shape, type): no action."""


class NonFiniteLogitsError(PolicyOutputError):
    """The forward pass gave NaN/Inf logits: no action can be chosen from them. ``h_next`` is
    the next hidden state it computed (the caller keeps it if finite)."""

    def __init__(self, message: str, h_next: F32) -> None:
        super().__init__(message)
        self.h_next = h_next


class ActorRuntime:
    """The shared actor's forward pass on NumPy arrays; immutable once built."""

    def __init__(self, spec: ActorSpec, tensors: Tensors, version: int = 0) -> None:
        self.spec = spec
        self.version = version
        self._features = get_transform(spec.features)
        self._enc = [
            (tensors[f"encoder.{k}.weight"].T.copy(), tensors[f"encoder.{k}.bias"])
            for k in range(len(spec.hidden_sizes))
        ]
        self._recurrent = spec.gru_hidden > 0  # else feed-forward: hidden [X, 0] passes through
        if self._recurrent:
            self._w_ih = tensors["gru.weight_ih"].T.copy()  # [in, 3H], gate order r, z, n
            self._w_hh = tensors["gru.weight_hh"].T.copy()  # [H, 3H]
            self._b_ih = tensors["gru.bias_ih"]
            self._b_hh = tensors["gru.bias_hh"]
        self._w_out = tensors["head.weight"].T.copy()
        self._b_out = tensors["head.bias"]

    @classmethod
    def from_bytes(cls, fmt: str, version: int, payload: bytes, sha256: str) -> ActorRuntime:
        """Build from the fields of a ``PolicyWeights`` message (validated; WeightsError if bad)."""
        spec, tensors = decode_actor(fmt, version, payload, sha256)
        return cls(spec, tensors, version)

    @classmethod
    def from_weights(cls, blob: ActorWeights) -> ActorRuntime:
        return cls.from_bytes(blob.format, blob.version, blob.payload, blob.sha256)

    @classmethod
    def from_file(cls, path: str | os.PathLike[str]) -> ActorRuntime:
        return cls.from_weights(load_actor_file(path))

    @property
    def hidden_size(self) -> int:
        return self.spec.gru_hidden

    def initial_state(self, n: int) -> F32:
        """Hidden state at the start of an episode for ``n`` robots: zeros [n, H]."""
        return np.zeros((n, self.spec.gru_hidden), dtype=np.float32)

    def _input(self, obs: npt.ArrayLike, robot_id: int | npt.ArrayLike | None) -> F32:
        x = np.asarray(obs, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != self.spec.obs_size:
            raise ValueError(f"obs must be [X, {self.spec.obs_size}], got {x.shape}")
        x = self._features(x)
        if not self.spec.use_robot_id:
            return x
        if robot_id is None:
            raise ValueError("this actor was trained with a one-hot robot id: pass robot_id")
        ids = np.broadcast_to(np.asarray(robot_id, dtype=np.int64), (x.shape[0],))
        if np.any(ids < 0) or np.any(ids >= self.spec.num_robots):
            raise ValueError(f"robot_id out of range [0, {self.spec.num_robots})")
        onehot = np.zeros((x.shape[0], self.spec.num_robots), dtype=np.float32)
        onehot[np.arange(x.shape[0]), ids] = 1.0
        return np.concatenate([x, onehot], axis=1)

    def step(
        self, obs: npt.ArrayLike, hidden: npt.ArrayLike, robot_id: int | npt.ArrayLike | None = None
    ) -> tuple[F32, F32]:
        """One step: returns (logits [X, A], next hidden [X, H])."""
        x = self._input(obs, robot_id)
        h = np.asarray(hidden, dtype=np.float32)
        for w, b in self._enc:
            x = np.maximum(x @ w + b, 0.0)
        if not self._recurrent:
            if h.shape != (x.shape[0], 0):
                raise ValueError(f"hidden must be [{x.shape[0]}, 0] (feed-forward actor), got "
                                 f"{h.shape}")
            return np.asarray(x @ self._w_out + self._b_out, dtype=np.float32), h
        gi = x @ self._w_ih + self._b_ih
        gh = h @ self._w_hh + self._b_hh
        g = self.spec.gru_hidden
        # both gates in one elementwise pass (the same float32 operations per element as two)
        rz = _sigmoid(gi[:, : 2 * g] + gh[:, : 2 * g])
        r, z = rz[:, :g], rz[:, g:]
        n = np.tanh(gi[:, 2 * g :] + r * gh[:, 2 * g :])
        h_next = np.asarray((1.0 - z) * n + z * h, dtype=np.float32)
        logits = np.asarray(h_next @ self._w_out + self._b_out, dtype=np.float32)
        return logits, h_next

    def act(
        self,
        obs: npt.ArrayLike,
        hidden: npt.ArrayLike,
        greedy: bool,
        rng: np.random.Generator,
        robot_id: int | npt.ArrayLike | None = None,
        *,
        temperature: float = 1.0,
    ) -> tuple[npt.NDArray[np.int64], F32, F32]:
        """Pick actions: returns (action [X], log-prob of it under the policy [X], next hidden
        [X, H]). Sampled play draws from softmax(logits / ``temperature``); the log-prob
        returned is always the policy's own (temperature 1), the one PPO trains on.
        NonFiniteLogitsError when a logit is NaN/Inf (never an action chosen from them)."""
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is reported below
            logits, h_next = self.step(obs, hidden, robot_id)
            logp = log_softmax(logits)
        if not np.isfinite(logits).all():  # argmax/sampling would still pick something
            raise NonFiniteLogitsError(
                f"the policy computed non-finite logits "
                f"{np.array2string(logits[0], precision=3)[:200]}; no action", h_next)
        action = choose_actions(logp, greedy, rng, temperature)
        chosen = logp[np.arange(len(action)), action]
        if not np.isfinite(chosen).all():  # finite logits so far apart that float32 overflows
            raise NonFiniteLogitsError("the chosen action's log-probability is not finite "
                                       "(logits overflow float32); no action", h_next)
        return action, chosen, h_next
