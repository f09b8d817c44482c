"""The ROS-free halves of the simulator and actor nodes: lock-step bookkeeping (missing -> stay,
malformed actions dropped by kind) and the actor's weights / observation validation."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from safetensors.numpy import load as st_load
from safetensors.numpy import save as st_save

from sdhn_policy.actor_core import ActorCore, Decision, Drop
from sdhn_policy.weights import ActorSpec, ActorWeights, WeightsError, encode_actor, sha256_hex
from sdhn_sim.lockstep import LockstepSim, SimConfig, SimConfigError

SPEC = ActorSpec(obs_size=57, num_actions=5)


def blob(version: int, seed: int = 0) -> ActorWeights:
    rng = np.random.default_rng(seed)
    tensors = {k: rng.standard_normal(s).astype(np.float32) * 0.3
               for k, s in SPEC.tensor_shapes().items()}
    return encode_actor(SPEC, tensors, version)


def offer(core: ActorCore, b: ActorWeights) -> None:
    core.offer_weights(b.format, b.version, b.payload, b.sha256)


# --- simulator ---------------------------------------------------------------------------------


def test_missing_actions_become_stay_and_are_counted() -> None:
    sim = LockstepSim(SimConfig(env="maif-tiny", seed=1, episodes=1, max_steps=3))
    f = sim.reset()
    assert sim.submit(0, f.episode, f.step, 1, version=2) is None
    assert not sim.complete and sim.missing() == [1, 2, 3]
    f, result = sim.advance()
    assert f.step == 1 and f.missed == 3 and result is None
    for _ in range(2):
        for i in range(4):
            sim.submit(i, f.episode, f.step, 0, version=3)
        assert sim.complete
        f, result = sim.advance()
    assert result is not None and f.truncated
    assert result.missed_actions == 3 and result.policy_version == 3 and result.length == 3
    assert sim.finished


@pytest.mark.parametrize("env,instance", [("maif-tiny", 7), ("maif-tiny", -1), ("rware-3", -1)])
def test_frames_and_results_carry_the_world_identity(env: str, instance: int) -> None:
    """Every frame and episode result names the world it shows (MAIF instance id; -1 for RWARE),
    and positions come from the single-env view for both kinds of world."""
    sim = LockstepSim(SimConfig(env=env, seed=3, instance=instance, max_steps=3))
    frame = sim.reset()
    want = sim.env.instance_id
    assert (want == instance) if instance >= 0 else (want >= 0) == env.startswith("maif")
    result = None
    while result is None:
        assert frame.instance_id == want
        assert frame.positions.shape == (sim.num_robots, 2)
        assert np.array_equal(frame.positions, sim.env.positions)
        frame, result = sim.advance()
    assert result.instance_id == want and frame.instance_id == want


def test_malformed_actions_are_dropped_by_kind() -> None:
    sim = LockstepSim(SimConfig(env="maif-tiny"))
    f = sim.reset()
    assert sim.submit(7, 0, 0, 1, 1) == "unknown_robot"
    assert sim.submit(0, 0, 1, 1, 1) == "future_step"
    assert sim.submit(0, 0, 0, 9, 1) == "action_out_of_range"
    assert sim.submit(0, 0, 0, 1, 1) is None
    assert sim.submit(0, 0, 0, 2, 1) == "duplicate_action"
    for i in range(1, 4):
        sim.submit(i, 0, 0, 0, 1)
    sim.advance()
    assert sim.submit(1, f.episode, f.step, 1, 1) == "stale_step"


@pytest.mark.parametrize("field,value", [("env", "nope"), ("step_deadline", 0.0),
                                         ("step_deadline", float("nan")), ("episodes", -1),
                                         ("instance", -2), ("start_timeout", -1.0)])
def test_bad_sim_config_names_the_field(field: str, value: object) -> None:
    with pytest.raises(SimConfigError, match=f"^{field}:.*allowed"):
        dataclasses.replace(SimConfig(), **{field: value}).validate()


# --- actor -------------------------------------------------------------------------------------


def test_actor_swaps_weights_between_steps_and_tags_actions() -> None:
    core = ActorCore(robot_id=1, num_robots=4, greedy=True, seed=0)
    obs = np.linspace(0, 1, 57, dtype=np.float32)
    assert isinstance(core.on_obs(0, 0, 1, 4, obs), Drop)  # no weights yet
    offer(core, blob(1))
    d = core.on_obs(0, 0, 1, 4, obs)
    assert isinstance(d, Decision) and d.version == 1
    offer(core, blob(2, seed=5))
    assert core.version == 1, "new weights wait for the next step"
    d = core.on_obs(0, 1, 1, 4, obs)
    assert isinstance(d, Decision) and d.version == 2
    assert core.on_obs(0, 2, 1, 4, obs, done=True) is None


@pytest.mark.parametrize("mutate,kind", [
    (lambda b: dataclasses.replace(b, sha256="0" * 64), "bad_sha256"),
    (lambda b: dataclasses.replace(b, format="other/9"), "unknown_format"),
    (lambda b: dataclasses.replace(b, payload=b.payload[:-8]), "bad_sha256"),
])
def test_bad_weights_are_rejected_and_old_ones_kept(mutate: object, kind: str) -> None:
    core = ActorCore(robot_id=0, num_robots=4, greedy=True, seed=0)
    offer(core, blob(1))
    bad = mutate(blob(2))  # type: ignore[operator]
    with pytest.raises(WeightsError) as e:
        offer(core, bad)
    assert e.value.kind == kind
    d = core.on_obs(0, 0, 0, 4, np.zeros(57, np.float32))
    assert isinstance(d, Decision) and d.version == 1


def test_wrong_shape_weights_are_rejected() -> None:
    good = blob(2)
    # A well-formed, correctly hashed payload whose tensors do not match the spec it declares.
    tensors = st_load(good.payload)
    tensors["head.bias"] = np.zeros(7, np.float32)
    meta = {"format": good.format, "version": "2", "spec": json.dumps(SPEC.to_json())}
    payload = st_save(tensors, metadata=meta)
    core = ActorCore(robot_id=0, num_robots=4, greedy=True, seed=0)
    with pytest.raises(WeightsError) as e:
        core.offer_weights(good.format, 2, payload, sha256_hex(payload))
    assert e.value.kind == "bad_tensors"


@pytest.mark.parametrize("obs,kind", [
    (np.zeros(56, np.float32), "wrong_obs_length"),
    (np.full(57, np.nan, np.float32), "non_finite_obs"),
    (np.full(57, np.inf, np.float32), "non_finite_obs"),
])
def test_malformed_observations_are_dropped(obs: np.ndarray, kind: str) -> None:
    core = ActorCore(robot_id=0, num_robots=4, greedy=True, seed=0)
    offer(core, blob(1))
    out = core.on_obs(0, 0, 0, 4, obs)
    assert isinstance(out, Drop) and out.kind == kind


def test_gru_state_resets_on_a_new_episode() -> None:
    core = ActorCore(robot_id=2, num_robots=4, greedy=True, seed=0)
    offer(core, blob(1))
    rng = np.random.default_rng(3)
    seq = [rng.standard_normal(57).astype(np.float32) for _ in range(5)]
    first = [core.on_obs(0, t, 2, 4, o) for t, o in enumerate(seq)]
    h_end = core.hidden.copy()  # type: ignore[union-attr]
    second = [core.on_obs(1, t, 2, 4, o) for t, o in enumerate(seq)]
    assert first == second, "same observations from a fresh episode give the same actions"
    assert np.array_equal(core.hidden, h_end)
    assert isinstance(core.on_obs(1, 2, 2, 4, seq[0]), Drop)  # stale step
    assert isinstance(core.on_obs(1, 9, 3, 4, seq[0]), Drop)  # another robot's observation
