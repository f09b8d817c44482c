"""sdhn_policy.team_size: an actor with one-hot robot ids moved to another team size (NumPy,
the warm start's and the zero-shot evaluation's one implementation)."""

from __future__ import annotations

import numpy as np

from sdhn_policy.team_size import for_team, input_tensor_name, resize_robot_ids
from sdhn_policy.weights import ActorSpec


def test_resize_keeps_obs_and_shared_ids_and_averages_new_ones() -> None:
    rng = np.random.default_rng(0)
    w = rng.normal(size=(4, 5 + 3)).astype(np.float32)  # 5 features, 3 ids
    wide = resize_robot_ids(w, 5, 6)
    assert wide.shape == (4, 11)
    np.testing.assert_array_equal(wide[:, :8], w)
    for j in range(8, 11):
        np.testing.assert_allclose(wide[:, j], w[:, 5:].mean(axis=1), rtol=1e-6)
    narrow = resize_robot_ids(w, 5, 2)
    np.testing.assert_array_equal(narrow, w[:, :7])


def test_for_team_resizes_only_an_actor_with_ids() -> None:
    spec = ActorSpec(obs_size=6, num_actions=5, hidden_sizes=(8,), gru_hidden=0,
                     use_robot_id=True, num_robots=2)
    tensors = {k: np.ones(s, dtype=np.float32) for k, s in spec.tensor_shapes().items()}
    new, out = for_team(spec, tensors, 4)
    assert new.num_robots == 4 and out[input_tensor_name(spec)].shape == \
        new.tensor_shapes()[input_tensor_name(new)]
    plain = ActorSpec(obs_size=6, num_actions=5, hidden_sizes=(8,), gru_hidden=0)
    tensors = {k: np.ones(s, dtype=np.float32) for k, s in plain.tensor_shapes().items()}
    same_spec, same = for_team(plain, tensors, 4)
    assert same is tensors and same_spec.input_size == plain.input_size
