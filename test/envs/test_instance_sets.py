"""MAIF instance sets: the fixed training set, a held-out set and a large training set."""

from __future__ import annotations

import numpy as np
import pytest

from sdhn_sim.envs import load_instances, make_env
from sdhn_sim.envs.maif_instances import _all_reachable


def test_sets_differ_and_are_deterministic():
    train = make_env("maif-tiny", instance_set="train").instances
    shipped = load_instances("maif-tiny")  # the shipped file, unchanged
    np.testing.assert_array_equal(train.obstacles, shipped.obstacles)
    np.testing.assert_array_equal(train.starts, shipped.starts)
    held = make_env("maif-tiny", instance_set="heldout").instances
    held2 = make_env("maif-tiny", instance_set="heldout").instances
    np.testing.assert_array_equal(held.obstacles, held2.obstacles)
    np.testing.assert_array_equal(held.starts, held2.starts)
    assert held.num_instances == 100 and held.config.size == train.config.size
    assert not any(np.array_equal(h, t) for h in held.obstacles for t in train.obstacles)
    large = make_env("maif-tiny", instance_set="large").instances
    assert large.num_instances == 1000
    assert not any(np.array_equal(h, t) for h in large.obstacles[:10] for t in held.obstacles)
    for m in range(held.obstacles.shape[0]):
        for f in range(held.starts.shape[1]):
            assert _all_reachable(held.obstacles[m], held.starts[m, f], held.goals[m, f])


def test_bad_instance_set():
    with pytest.raises(ValueError, match="instance_set"):
        make_env("maif-tiny", instance_set="test")
