"""Training-side actor: the shared MAPPO/SDHN policy network as a torch module.

The only torch file in ``sdhn_policy``. Local observation (optionally + one-hot robot id) -> MLP
encoder -> GRU cell -> categorical logits. ``export()`` produces the safetensors blob that
``sdhn_policy.actor_runtime.ActorRuntime`` runs without torch.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from sdhn_policy.weights import ActorSpec, ActorWeights, encode_actor


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
        self.gru = nn.GRUCell(width, spec.gru_hidden)
        self.head = nn.Linear(spec.gru_hidden, spec.num_actions)
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
        h = self.gru(self.encoder(x), h)
        return self.head(h), h

    def forward_sequence(self, x: Tensor, h0: Tensor, resets: Tensor) -> Tensor:
        """Re-run stored sequences: x [T, X, in], h0 [X, H], resets [T, X] bool (hidden is zeroed
        before step t where resets[t]) -> logits [T, X, A]."""
        feats = self.encoder(x)
        keep = (~resets).to(x.dtype).unsqueeze(-1)
        h = h0
        hs = []
        for t in range(x.shape[0]):
            h = self.gru(feats[t], h * keep[t])
            hs.append(h)
        return self.head(torch.stack(hs))

    def tensors(self) -> dict[str, Tensor]:
        """Parameters under the names of ``ActorSpec.tensor_shapes``."""
        out: dict[str, Tensor] = {}
        linears = [m for m in self.encoder if isinstance(m, nn.Linear)]
        for k, lin in enumerate(linears):
            out[f"encoder.{k}.weight"] = lin.weight
            out[f"encoder.{k}.bias"] = lin.bias
        out["gru.weight_ih"] = self.gru.weight_ih
        out["gru.weight_hh"] = self.gru.weight_hh
        out["gru.bias_ih"] = self.gru.bias_ih
        out["gru.bias_hh"] = self.gru.bias_hh
        out["head.weight"] = self.head.weight
        out["head.bias"] = self.head.bias
        return out

    def export(self, version: int) -> ActorWeights:
        """The deployable blob (format, version, payload, sha256)."""
        arrays = {k: v.detach().cpu().float().numpy() for k, v in self.tensors().items()}
        return encode_actor(self.spec, arrays, version)
