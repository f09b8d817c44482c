"""Skewness of hyperedge degrees and the skewness loss (eqs. for gamma, Sk and skew_loss)."""

from __future__ import annotations

import torch
from torch import Tensor


def hyperedge_degrees(incidence: Tensor) -> Tensor:
    """b_j = sum_i H_ij (degree of hyperedge j, eq. HGCN's B); [..., N, M] -> [..., M].

    Takes the straight-through H, so gradients reach the generator f_g."""
    return incidence.sum(-2)


def sample_skewness(b: Tensor) -> Tensor:
    """gamma = E[(b - E b)^3] / (E[(b - E b)^2])^(3/2) over the last axis (unlabelled eq. for
    gamma; the biased sample skewness, == scipy.stats.skew(bias=True)).

    Guard: where all degrees are equal (zero variance) gamma is defined as 0, with a finite
    (zero) gradient instead of 0/0."""
    c = b - b.mean(-1, keepdim=True)
    m2 = (c * c).mean(-1)
    m3 = (c * c * c).mean(-1)
    ok = m2 > 0
    m2_safe = torch.where(ok, m2, torch.ones_like(m2))
    return torch.where(ok, m3 / m2_safe.pow(1.5), torch.zeros_like(m3))


def squashed_skewness(gamma: Tensor) -> Tensor:
    """Sk = 2 / (1 + e^-gamma) - 1 in (-1, 1) (unlabelled eq. for Sk)."""
    return 2.0 * torch.sigmoid(gamma) - 1.0


def skewness_loss(sk: Tensor, target: float) -> Tensor:
    """L_Sk = (Sk - lambda_Sk)^2 (eq. skew_loss), averaged over the batch."""
    return ((sk - target) ** 2).mean()
