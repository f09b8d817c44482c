"""Small network building blocks shared by the critics and mixers."""

from __future__ import annotations

import itertools

from torch import nn


def mlp(sizes: list[int]) -> nn.Sequential:
    """Linear + ReLU for each consecutive pair of ``sizes``."""
    layers: list[nn.Module] = []
    for a, b in itertools.pairwise(sizes):
        layers += [nn.Linear(a, b), nn.ReLU()]
    return nn.Sequential(*layers)
