"""Training-side actor: the shared MAPPO/SDHN policy network as a torch module.

The only torch file in ``sdhn_policy``. Local observation (optionally + one-hot robot id) -> MLP
encoder -> GRU cell (none when ``gru_hidden`` is 0: feed-forward) -> categorical logits.
``export()`` produces the safetensors blob that ``sdhn_policy.actor_runtime.ActorRuntime`` runs
without torch.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import torch
from torch import Tensor, nn

from sdhn_policy.weights import ActorSpec, ActorWeights, encode_actor

SequenceFn = Callable[[nn.GRU, Tensor, Tensor, Tensor], tuple[Tensor, Tensor]]


def gru_sequence(gru: nn.GRU, x: Tensor, h0: Tensor, resets: Tensor) -> tuple[Tensor, Tensor]:
    """Run ``gru`` over x [T, B, in] from h0 [L, B, H], zeroing the hidden state of env b before
    step t where resets[t, b]. One fused ``nn.GRU`` call per segment between reset times (not
    one call per step). Returns (outputs [T, B, H], hiddens [T, L, B, H]); ``hiddens[t]`` is
    the hidden state after step t, filled (detached) only at segment ends, i.e. at the last step
    and wherever resets[t + 1] has a True."""
    t_len = x.shape[0]
    cuts = [0, *sorted(set(resets.any(1).nonzero().flatten().tolist()) - {0}), t_len]
    keep = (~resets).to(x.dtype)[:, None, :, None]  # [T, 1, B, 1]
    hiddens = x.new_zeros(t_len, *h0.shape)
    outs, h = [], h0
    for start, end in itertools.pairwise(cuts):
        out, h = gru(x[start:end], h * keep[start])
        outs.append(out)
        hiddens[end - 1] = h.detach()
    return torch.cat(outs), hiddens


class Actor(nn.Module):
    """Shared actor. Robots are batch rows: the network never mixes robots."""

    def __init__(self, spec: ActorSpec) -> None:
        super().__init__()
        spec.check()
        self.spec = spec
        layers: list[nn.Module] = []
        width = spec.input_size
        for h in spec.hidden_sizes:
            layers += [nn.Linear(width, h), nn.ReLU()]
            width = h
        self.encoder = nn.Sequential(*layers)
        # feed-forward (gru_hidden 0): no GRU, and hidden states of width 0 pass through
        self.gru = nn.GRU(width, spec.gru_hidden) if spec.gru_hidden > 0 else None
        # how forward_sequence runs the GRU (a trainer may swap in an equal, faster one)
        self.gru_sequence: SequenceFn = gru_sequence
        self.head = nn.Linear(spec.gru_hidden or width, spec.num_actions)
        nn.init.orthogonal_(self.head.weight, gain=0.01)  # near-uniform initial policy
        nn.init.zeros_(self.head.bias)

    def with_robot_id(self, obs: Tensor) -> Tensor:
        """[..., N, D] -> [..., N, D(+N)]: append the one-hot robot id if the spec asks for it."""
        if not self.spec.use_robot_id:
            return obs
        n = obs.shape[-2]
        if n != self.spec.num_robots:
            raise ValueError(f"obs has {n} robots, actor was built for {self.spec.num_robots}")
        eye = torch.eye(n, dtype=obs.dtype, device=obs.device).expand(*obs.shape[:-1], n)
        return torch.cat([obs, eye], dim=-1)

    def step(self, x: Tensor, h: Tensor) -> tuple[Tensor, Tensor]:
        """One step on inputs [X, input_size] and hidden [X, H] -> (logits [X, A], hidden)."""
        if self.gru is None:
            return self.head(self.encoder(x)), h
        out, h_next = self.gru(self.encoder(x)[None], h[None])
        return self.head(out[0]), h_next[0]

    def forward_sequence(self, x: Tensor, h0: Tensor, resets: Tensor) -> Tensor:
        """Re-run stored sequences: x [T, X, in], h0 [X, H], resets [T, X] bool (hidden is zeroed
        before step t where resets[t]) -> logits [T, X, A]."""
        if self.gru is None:
            return self.head(self.encoder(x))
        out, _ = self.gru_sequence(self.gru, self.encoder(x), h0[None], resets)
        return self.head(out)

    def tensors(self) -> dict[str, Tensor]:
        """Parameters under the names of ``ActorSpec.tensor_shapes``."""
        out: dict[str, Tensor | nn.Module] = {}
        linears = [m for m in self.encoder if isinstance(m, nn.Linear)]
        for k, lin in enumerate(linears):
            out[f"encoder.{k}.weight"] = lin.weight
            out[f"encoder.{k}.bias"] = lin.bias
        if self.gru is not None:
            out["gru.weight_ih"] = self.gru.weight_ih_l0
            out["gru.weight_hh"] = self.gru.weight_hh_l0
            out["gru.bias_ih"] = self.gru.bias_ih_l0
            out["gru.bias_hh"] = self.gru.bias_hh_l0
        out["head.weight"] = self.head.weight
        out["head.bias"] = self.head.bias
        return {k: v for k, v in out.items() if isinstance(v, Tensor)}

    def export(self, version: int) -> ActorWeights:
        """The deployable blob (format, version, payload, sha256)."""
        arrays = {k: v.detach().cpu().float().numpy() for k, v in self.tensors().items()}
        return encode_actor(self.spec, arrays, version)
