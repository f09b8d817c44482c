"""A GRU over stored sequences with a hand-written backward: the same arithmetic as ``nn.GRU``
(checked to 1e-5, gradients too, in test/algo/test_fused_gru.py), fewer ops per time step.

Why: on CPU ``nn.GRU`` runs one cell per time step and autograd records every op of every cell
(about a dozen nodes per step and layer), so a rollout of T = 128 steps costs thousands of tiny
forward and backward ops whose per-op overhead dominates. Here the input projections of all T
steps (and, in the backward, the weight gradients and the input gradient) are single matrix
products, and the recurrence runs without autograd: forward 7 ops and backward 4 ops per step.
Resets are a mask on the carried hidden state, so the whole sequence is one call (no segments).

``fused_gru_sequence(gru, x, h0, resets)`` is a drop-in for ``sdhn_policy.actor_torch.
gru_sequence``; ``hiddens`` is filled at every step (a superset of what ``gru_sequence`` fills).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from sdhn_policy.actor_torch import gru_sequence


def _forward_loop(gi: Tensor, h0: Tensor, w_hh: Tensor, b_hh: Tensor, *,
                  keep: Tensor | None, reset_steps: list[bool]
                  ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The recurrence given gi = x W_ih^T + b_ih [T, B, 3H]. Returns (hist [T + 1, B, H]: h0,
    then the hidden state after each step, so ``hist[1:]`` is the output and ``hist[:-1]`` the
    (unmasked) state each step starts from, without a copy; gh = h_prev W_hh^T + b_hh
    [T, B, 3H], rz = (r, z) [T, B, 2H], n [T, B, H]). Every per-step tensor is a slice made once
    (``unbind``) and written in place (``out=``), so a step is 7 ops."""
    t_len, b, h3 = gi.shape
    hs = h3 // 3
    hist = gi.new_empty(t_len + 1, b, hs)
    hist[0] = h0
    out = hist[1:]
    gh = gi.new_empty(t_len, b, h3)
    rz = gi.new_empty(t_len, b, 2 * hs)
    n = gi.new_empty(t_len, b, hs)
    gi_rz, gi_n = gi[..., :2 * hs].unbind(0), gi[..., 2 * hs:].unbind(0)
    gh_s, gh_rz, gh_n = gh.unbind(0), gh[..., :2 * hs].unbind(0), gh[..., 2 * hs:].unbind(0)
    rz_s, r_s, z_s = rz.unbind(0), rz[..., :hs].unbind(0), rz[..., hs:].unbind(0)
    n_s, out_s = n.unbind(0), out.unbind(0)
    w_hh_t = w_hh.t()
    h = h0
    for t in range(t_len):
        if keep is not None and reset_steps[t]:
            h = h * keep[t]
        torch.addmm(b_hh, h, w_hh_t, out=gh_s[t])
        torch.sigmoid(gi_rz[t] + gh_rz[t], out=rz_s[t])
        torch.tanh(torch.addcmul(gi_n[t], r_s[t], gh_n[t]), out=n_s[t])
        # h' = (1 - z) n + z h = n + z (h - n)
        torch.addcmul(n_s[t], z_s[t], h - n_s[t], out=out_s[t])
        h = out_s[t]
    return hist, gh, rz, n


class _GRULayer(torch.autograd.Function):
    """One GRU layer over a whole sequence with reset masks; exact ``nn.GRU`` arithmetic."""

    @staticmethod
    def forward(ctx: Any, x: Tensor, h0: Tensor, w_ih: Tensor, w_hh: Tensor,  # noqa: PLR0917
                b_ih: Tensor, b_hh: Tensor, keep: Tensor | None, reset_steps: list[bool]
                ) -> Tensor:
        t_len, b, _ = x.shape
        gi = torch.addmm(b_ih, x.reshape(t_len * b, -1), w_ih.t()).reshape(t_len, b, -1)
        hist, gh, rz, n = _forward_loop(gi, h0, w_hh, b_hh, keep=keep, reset_steps=reset_steps)
        ctx.save_for_backward(x, w_ih, w_hh, hist, gh, rz, n, keep)
        ctx.reset_steps = reset_steps
        return hist[1:]

    @staticmethod
    def backward(ctx: Any, grad_out: Tensor) -> tuple[Tensor | None, ...]:
        x, w_ih, w_hh, hist, gh, rz, n, keep = ctx.saved_tensors
        reset_steps: list[bool] = ctx.reset_steps
        t_len, b, hs = n.shape
        # h_prev[t]: the (reset-masked) hidden state step t starts from, [T, B, H]
        h_prev = hist[:-1] * keep if keep is not None else hist[:-1]
        r, z, ghn = rz[..., :hs], rz[..., hs:], gh[..., 2 * hs:]
        # pre_r = gi_r + gh_r, pre_z = gi_z + gh_z, pre_n = gi_n + r gh_n; h' = n + z (h - n).
        # d pre = dh * a with a per gate, vectorised over all T (a_n: d pre_n / dh). Each gate's
        # factor is written into its slice of a_gh (no cat: at the actor's T x b*N rows every
        # full-size temporary and copy is ~1 ms); same products in the same order as before.
        one_minus_z = 1.0 - z
        a_n = (1.0 - n * n).mul_(one_minus_z)
        a_gh = grad_out.new_empty(t_len, b, 3, hs)
        torch.mul(a_n, ghn, out=a_gh[:, :, 0]).mul_(r).mul_(1.0 - r)  # d pre_r / dh
        torch.sub(h_prev, n, out=a_gh[:, :, 1]).mul_(z).mul_(one_minus_z)  # d pre_z / dh
        torch.mul(a_n, r, out=a_gh[:, :, 2])  # d gh_n / dh
        d_gh = grad_out.new_empty(t_len, b, 3, hs)  # d(h_prev W_hh^T + b_hh) per step
        dh_all = grad_out.new_empty(t_len, b, hs)  # d out[t], all paths
        a_gh_s = a_gh.unbind(0)
        d_gh_s, d_gh_flat = d_gh.unbind(0), d_gh.view(t_len, b, 3 * hs).unbind(0)
        dh_s, g_s, z_s = dh_all.unbind(0), grad_out.unbind(0), z.unbind(0)
        dh = grad_out.new_zeros(b, hs)
        for t in range(t_len - 1, -1, -1):
            torch.add(dh, g_s[t], out=dh_s[t])
            torch.mul(dh_s[t][:, None, :], a_gh_s[t], out=d_gh_s[t])
            dh = torch.addmm(dh_s[t] * z_s[t], d_gh_flat[t], w_hh)  # d h_prev
            if keep is not None and reset_steps[t]:
                dh = dh * keep[t]
        d_gh2 = d_gh.view(t_len * b, 3 * hs)
        d_gi = torch.empty_like(d_gh)  # d(x W_ih^T + b_ih): d_gh's r, z parts, then the n part
        d_gi[:, :, :2] = d_gh[:, :, :2]
        torch.mul(dh_all, a_n, out=d_gi[:, :, 2])
        d_gi = d_gi.view(t_len * b, 3 * hs)
        x2 = x.reshape(t_len * b, -1)
        grad_x = (d_gi @ w_ih).view(x.shape) if ctx.needs_input_grad[0] else None
        grad_h0 = dh if ctx.needs_input_grad[1] else None
        grad_w_ih = d_gi.t() @ x2 if ctx.needs_input_grad[2] else None
        grad_w_hh = d_gh2.t() @ h_prev.reshape(t_len * b, hs) if ctx.needs_input_grad[3] else None
        grad_b_ih = d_gi.sum(0) if ctx.needs_input_grad[4] else None
        grad_b_hh = d_gh2.sum(0) if ctx.needs_input_grad[5] else None
        return grad_x, grad_h0, grad_w_ih, grad_w_hh, grad_b_ih, grad_b_hh, None, None


def gru_layer(x: Tensor, h0: Tensor, weights: tuple[Tensor, Tensor, Tensor, Tensor],
              resets: Tensor | None = None) -> Tensor:
    """One GRU layer: x [T, B, in], h0 [B, H], weights (w_ih, w_hh, b_ih, b_hh) as in
    ``nn.GRU``, resets [T, B] bool (hidden zeroed before step t) -> outputs [T, B, H] (the
    hidden state after each step)."""
    w_ih, w_hh, b_ih, b_hh = weights
    keep: Tensor | None = None
    reset_steps: list[bool] = []
    if resets is not None and bool(resets.any()):
        keep = (~resets).to(x.dtype)[:, :, None]
        reset_steps = resets.any(1).tolist()
    if not (torch.is_grad_enabled() and any(
            t.requires_grad for t in (x, h0, w_ih, w_hh, b_ih, b_hh))):
        with torch.no_grad():
            t_len, b, _ = x.shape
            gi = torch.addmm(b_ih, x.reshape(t_len * b, -1), w_ih.t()).reshape(t_len, b, -1)
            return _forward_loop(gi, h0, w_hh, b_hh, keep=keep, reset_steps=reset_steps)[0][1:]
    out: Tensor = _GRULayer.apply(x, h0, w_ih, w_hh, b_ih, b_hh, keep, reset_steps)
    return out


def fused_gru_sequence(gru: nn.GRU, x: Tensor, h0: Tensor, resets: Tensor
                       ) -> tuple[Tensor, Tensor]:
    """Drop-in for ``gru_sequence``: ``gru`` (unidirectional, batch_first=False, with biases, no
    dropout between layers) over x [T, B, in] from h0 [L, B, H] with resets [T, B] -> (outputs
    [T, B, H], hiddens [T, L, B, H], detached: the hidden state after every step where a
    gradient is needed; where none is (no_grad, the target critic), this *is* ``gru_sequence``,
    which fills ``hiddens`` at segment ends only, as its callers expect)."""
    if gru.bidirectional or gru.batch_first or not gru.bias or gru.proj_size:
        raise ValueError("fused_gru_sequence supports plain unidirectional GRUs with biases")
    if gru.dropout and gru.training and gru.num_layers > 1:
        raise ValueError("fused_gru_sequence does not implement inter-layer dropout")
    if not (torch.is_grad_enabled() and (x.requires_grad or h0.requires_grad
                                         or any(p.requires_grad for p in gru.parameters()))):
        # nothing to differentiate: nn.GRU's own C++ loop is the fastest forward
        return gru_sequence(gru, x, h0, resets)
    layers = []
    inp = x
    for k in range(gru.num_layers):
        weights = tuple(getattr(gru, f"{w}_l{k}")
                        for w in ("weight_ih", "weight_hh", "bias_ih", "bias_hh"))
        inp = gru_layer(inp, h0[k], weights, resets)
        layers.append(inp.detach())
    return inp, torch.stack(layers, dim=1)


def use_fused_gru(module: nn.Module, fused: bool = True) -> None:
    """Point every submodule that runs stored sequences through a swappable ``gru_sequence``
    (``Actor``, ``HypergraphGenerator``) at the fused one (or back at the straightforward
    ``sdhn_policy.actor_torch.gru_sequence``)."""
    for m in module.modules():
        if "gru_sequence" in vars(m):
            setattr(m, "gru_sequence", fused_gru_sequence if fused else gru_sequence)  # noqa: B010
