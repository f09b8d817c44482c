"""Actor input features: the transform, its use by the runtime (raw obs in), the feature env the
learners train on, and the weights format that records the transform."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.actor_torch import Actor
from sdhn_policy.features import MAIF_EGO, feature_size, maif_ego
from sdhn_policy.weights import ActorSpec, ActorWeights, WeightsError, decode_weights, sha256_hex
from sdhn_sim.envs import make_env
from sdhn_train.config import Config
from sdhn_train.env_features import FeatureEnv, make_training_env, unwrap
from sdhn_train.envinfo import EnvInfo, actor_spec


def maif_obs_sequence(t_len: int = 60, seed: int = 3) -> np.ndarray:
    """[T, N, 57] real maif-tiny observations under random actions (with episode ends)."""
    env = make_env("maif-tiny", num_envs=1, seed=seed, max_steps=25)
    obs, _ = env.reset()
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(t_len):
        out.append(obs[0])
        obs = env.step(rng.integers(0, 5, (1, env.num_robots))).obs
    return np.stack(out)


def test_maif_ego_features_on_a_known_observation() -> None:
    size = 12
    obs = np.zeros(57, np.float32)
    # robot at (2, 3), centroid (4, 4), goal (9, 3), goal centroid (10, 10)
    obs[:8] = np.array([2, 3, 4, 4, 9, 3, 10, 10]) / (size - 1)
    win = np.zeros((7, 7), np.float32)
    win[2, 3] = 1  # obstacle above (up)
    win[3, 4] = 2  # robot to the right
    win[0, 0] = 1
    obs[8:] = win.reshape(-1)
    f = maif_ego(obs)
    assert f.shape == (feature_size(MAIF_EGO, 57),) == (114,)
    np.testing.assert_allclose(f[:2] * (size - 1), [7, 0], atol=1e-5)  # dx, dy
    np.testing.assert_array_equal(f[2:4], [1, 0])  # signs
    assert f[4] * (size - 1) == pytest.approx(7) and f[5] == 0  # L1, not on goal
    # formation error: (2 - 4) - (9 - 10) = -1, (3 - 4) - (3 - 10) = 6
    np.testing.assert_allclose(f[6:8] * (size - 1), [-1, 6], atol=1e-5)
    np.testing.assert_array_equal(f[8:10], [-1, 1])
    np.testing.assert_allclose(f[10:12] * (size - 1), [6, 6], atol=1e-5)
    np.testing.assert_array_equal(f[12:16], [1, 0, 0, 1])  # up and right blocked
    assert f[16:65].sum() == 2 and f[65:114].sum() == 1
    on = obs.copy()
    on[4:6] = on[0:2]
    assert maif_ego(on)[5] == 1.0 and maif_ego(on)[4] == 0.0


def test_maif_ego_of_one_row_has_the_bits_of_its_row_in_a_batch() -> None:
    """The actor computes one robot's features per step, the learner a batch at once: the same
    bits either way, on real observations and on edge values (on goal, NaN, infinities)."""
    obs = maif_obs_sequence().reshape(-1, 57)
    rng = np.random.default_rng(5)
    edges = obs[:40].copy()
    edges[:, :8] = rng.choice(np.array([0, 1, -1, 1e-5, np.nan, np.inf], np.float32),
                              edges[:, :8].shape)
    edges[::3, 4:6] = edges[::3, 0:2]
    for rows in (obs, edges):
        with np.errstate(invalid="ignore"):
            batch = maif_ego(rows)
            alone = np.stack([maif_ego(r) for r in rows])
            paired = maif_ego(rows.reshape(-1, 2, 57))
        assert batch.dtype == alone.dtype == np.float32
        np.testing.assert_array_equal(batch.view(np.uint32), alone.view(np.uint32))
        np.testing.assert_array_equal(paired.reshape(-1, 114).view(np.uint32),
                                      batch.view(np.uint32))


def test_features_of_one_robot_use_its_own_observation_only() -> None:
    obs = maif_obs_sequence(10)  # [T, N, 57]
    batched = maif_ego(obs)
    for i in range(obs.shape[1]):
        np.testing.assert_array_equal(batched[:, i], maif_ego(obs[:, i]))


@pytest.mark.parametrize("robot_id", [False, True])
def test_runtime_on_raw_obs_equals_torch_on_features(robot_id: bool) -> None:
    spec = ActorSpec(obs_size=57, num_actions=5, features=MAIF_EGO, use_robot_id=robot_id,
                     num_robots=4 if robot_id else 0)
    assert spec.input_size == 114 + (4 if robot_id else 0)
    torch.manual_seed(0)
    actor = Actor(spec)
    with torch.no_grad():
        for p in actor.parameters():
            p.add_(0.3 * torch.randn_like(p))
    rt = ActorRuntime.from_weights(actor.export(version=2))
    assert rt.spec.features == MAIF_EGO
    obs = maif_obs_sequence()  # raw
    t_len, n = obs.shape[:2]
    h = rt.initial_state(n)
    ids = np.arange(n) if robot_id else None
    got = []
    for t in range(t_len):
        logits, h = rt.step(obs[t], h, robot_id=ids)
        got.append(logits)
    with torch.no_grad():
        x = actor.with_robot_id(torch.from_numpy(maif_ego(obs)))
        want = actor.forward_sequence(x, torch.zeros(n, spec.gru_hidden),
                                      torch.zeros(t_len, n, dtype=torch.bool))
    np.testing.assert_allclose(np.stack(got), want.numpy(), atol=1e-5, rtol=0)


def v1_blob() -> ActorWeights:
    """Weights as ``sdhn-actor/1`` wrote them (no features in the spec)."""
    from safetensors.numpy import save

    spec, tensors = decode_weights(Actor(ActorSpec(obs_size=57, num_actions=5)).export(1))
    old_spec = {k: v for k, v in spec.to_json().items() if k != "features"}
    payload = save(dict(tensors), metadata={"format": "sdhn-actor/1", "version": "1",
                                            "spec": json.dumps(old_spec)})
    return ActorWeights("sdhn-actor/1", 1, payload, sha256_hex(payload))


def test_v1_weights_are_refused_with_one_line() -> None:
    with pytest.raises(WeightsError) as err:
        ActorRuntime.from_weights(v1_blob())
    msg = str(err.value)
    assert "sdhn-actor/1" in msg and "sdhn-actor/2" in msg and "\n" not in msg


def test_unknown_features_are_refused() -> None:
    with pytest.raises(WeightsError, match="feature"):
        ActorSpec(obs_size=57, num_actions=5, features="maif-ego/9").check()
    with pytest.raises(WeightsError, match="57"):
        ActorSpec(obs_size=10, num_actions=5, features=MAIF_EGO).check()


def test_feature_env_transforms_obs_state_and_final_obs() -> None:
    cfg = Config()
    cfg.env.name, cfg.env.max_steps = "maif-tiny", 5
    env = make_training_env(cfg, make_env, 3, 7)
    raw = make_env("maif-tiny", 3, 7, max_steps=5)
    assert isinstance(env, FeatureEnv) and unwrap(env).reward_name == "corrected"
    assert env.reward_name == "corrected"
    info = EnvInfo.of(env)
    assert (info.obs_size, info.state_size, info.raw_obs_size) == (114, 4 * 114, 57)
    spec = actor_spec(cfg.actor, info)
    assert (spec.obs_size, spec.features, spec.input_size) == (57, MAIF_EGO, 114)
    obs, state = env.reset()
    robs, _ = raw.reset()
    np.testing.assert_array_equal(obs, maif_ego(robs))
    np.testing.assert_array_equal(state, maif_ego(robs).reshape(3, -1))
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(6):  # crosses an episode end
        a = rng.integers(0, 5, (3, 4))
        res, rres = env.step(a), raw.step(a)
        np.testing.assert_array_equal(res.obs, maif_ego(rres.obs))
        np.testing.assert_array_equal(res.final_obs, maif_ego(rres.final_obs))
        np.testing.assert_array_equal(res.final_state, maif_ego(rres.final_obs).reshape(3, -1))
        np.testing.assert_array_equal(res.reward, rres.reward)
        ends += int(res.truncated.sum())
    assert ends == 3


def test_rware_keeps_identity() -> None:
    cfg = Config()
    cfg.env.name = "rware-3"
    env = make_training_env(cfg, make_env, 2, 0)
    assert not isinstance(env, FeatureEnv)
    assert actor_spec(cfg.actor, EnvInfo.of(env)).features == "identity"


def test_featurize_assembled_rollout_also_with_an_empty_prefix() -> None:
    from sdhn_train.env_features import featurize_assembled
    from sdhn_train.rollout import Rollout
    from sdhn_train.transitions import AssembledRollout

    obs = maif_obs_sequence(5)[:, None]  # [T, 1, N, 57]
    t, n = obs.shape[0], obs.shape[2]
    r = Rollout(obs, obs.reshape(t, 1, -1), np.zeros((t, 1, n), np.int64),
                np.zeros((t, 1, n), np.float32), np.zeros((t, 1), np.float32),
                np.zeros((t, 1), bool), np.zeros((t, 1), bool), obs, obs.reshape(t, 1, -1),
                np.zeros((1, n, 8), np.float32))
    for p in (0, 2):
        a = AssembledRollout(r, np.zeros((t, n), np.int64), [(0, k) for k in range(t)],
                             obs[:p, 0], obs[:p, 0].reshape(p, n * 57))
        f = featurize_assembled(a, MAIF_EGO)
        f.rollout.validate()
        np.testing.assert_array_equal(f.rollout.state, maif_ego(obs).reshape(t, 1, -1))
        assert f.prefix_obs.shape == (p, n, 114) and f.prefix_state.shape == (p, n * 114)


def test_reward_normalizer_scales_by_the_return_std() -> None:
    from sdhn_train.normalize import RewardNormalizer
    from sdhn_train.rollout import Rollout

    t, b = 200, 4
    rng = np.random.default_rng(0)
    rewards = (rng.normal(size=(t, b)) * 50).astype(np.float32)
    z = np.zeros((t, b), bool)
    r = Rollout(np.zeros((t, b, 1, 1), np.float32), np.zeros((t, b, 1), np.float32),
                np.zeros((t, b, 1), np.int64), np.zeros((t, b, 1), np.float32), rewards.copy(),
                z, z, np.zeros((t, b, 1, 1), np.float32), np.zeros((t, b, 1), np.float32),
                np.zeros((b, 1, 1), np.float32))
    norm = RewardNormalizer(b, gamma=0.0)  # gamma 0: the "return" is the reward itself
    out = norm(r)
    np.testing.assert_allclose(out.rewards, rewards / rewards.std(), rtol=2e-3)


def test_warm_start_copies_an_actor_across_team_sizes(tmp_path) -> None:
    from sdhn_policy.weights import save_actor_file
    from sdhn_train.config import ConfigError
    from sdhn_train.warm_start import load_actor_into

    torch.manual_seed(1)
    solo = Actor(ActorSpec(obs_size=57, num_actions=5, features=MAIF_EGO))
    path = tmp_path / "solo.safetensors"
    save_actor_file(path, solo.export(4))
    team = Actor(ActorSpec(obs_size=57, num_actions=5, features=MAIF_EGO))
    assert load_actor_into(team, path) == 4
    x = torch.from_numpy(maif_ego(maif_obs_sequence(3)))  # [T, 4, 114]
    h0, resets = torch.zeros(4, 64), torch.zeros(3, 4, dtype=torch.bool)
    with torch.no_grad():
        torch.testing.assert_close(team.forward_sequence(x, h0, resets),
                                   solo.forward_sequence(x, h0, resets))
    other = Actor(ActorSpec(obs_size=57, num_actions=5, features="identity"))
    with pytest.raises(ConfigError, match="differs"):
        load_actor_into(other, path)
    with pytest.raises(ConfigError, match="init_from"):
        load_actor_into(team, tmp_path / "missing.safetensors")
