"""Weight blobs are canonical: the same tensors always give the same bytes and checksum."""

from __future__ import annotations

import numpy as np

from sdhn_policy.weights import ActorSpec, decode_actor, encode_actor


def test_identical_weights_encode_to_identical_bytes() -> None:
    # safetensors orders its metadata differently from call to call; the blob must not.
    spec = ActorSpec(obs_size=5, num_actions=3, hidden_sizes=(8,), gru_hidden=4)
    rng = np.random.default_rng(0)
    tensors = {
        k: rng.standard_normal(s).astype(np.float32) for k, s in spec.tensor_shapes().items()
    }
    hashes = {encode_actor(spec, tensors, version=3).sha256 for _ in range(20)}
    assert len(hashes) == 1, f"{len(hashes)} different checksums for the same weights"
    blob = encode_actor(spec, tensors, version=3)
    _, decoded = decode_actor(blob.format, blob.version, blob.payload, blob.sha256)
    for name, value in tensors.items():
        np.testing.assert_array_equal(decoded[name], value)


# --- crafted and fuzzed payloads: every one is accepted-and-valid or a counted rejection -------

from collections import Counter  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
from faults.crafted_weights import ATTACKS, mutations, write_crafted_file  # noqa: E402

from sdhn_policy.actor_core import ActorCore, Decision  # noqa: E402
from sdhn_policy.actor_runtime import ActorRuntime  # noqa: E402
from sdhn_policy.weights import (  # noqa: E402
    ActorWeights,
    WeightsError,
    load_actor_file,
    save_actor_file,
    sha256_hex,
    validate_tensors,
)

SPEC = ActorSpec(obs_size=6, num_actions=4, hidden_sizes=(8,), gru_hidden=4)


def blob(version: int) -> ActorWeights:
    rng = np.random.default_rng(version)
    return encode_actor(SPEC, {k: rng.normal(0, 0.3, s).astype(np.float32)
                               for k, s in SPEC.tensor_shapes().items()}, version)


def acts(core: ActorCore, episode: int, obs_size: int = SPEC.obs_size) -> Decision:
    out = core.on_obs(episode, 0, core.robot_id, core.num_robots,
                      np.linspace(0, 1, obs_size, dtype=np.float32))
    assert isinstance(out, Decision), f"the core no longer acts: {out}"
    assert core.runtime is not None and 0 <= out.action < core.runtime.spec.num_actions, out
    return out


@pytest.mark.parametrize("attack", sorted(ATTACKS))
def test_crafted_header_is_a_rejection_not_a_crash(attack: str) -> None:
    # Before the bounded parser these escaped as RecursionError / OverflowError / ValueError
    # (digit limit), past the actor's drop-and-count path: every actor exited on one message.
    payload = ATTACKS[attack](blob(1))
    core = ActorCore(robot_id=0, num_robots=1, greedy=True, seed=0,
                     runtime=ActorRuntime.from_weights(blob(1)))
    with pytest.raises(WeightsError) as rejected:
        core.offer_weights("sdhn-actor/2", 1 + 1, payload, sha256_hex(payload))
    assert len(rejected.value.reason) < 400, "a crafted payload made a huge log line"
    assert acts(core, 0).version == 1  # the old weights stay in use


@pytest.mark.parametrize("attack", sorted(ATTACKS))
def test_crafted_weights_file_is_a_weights_error(tmp_path: Path, attack: str) -> None:
    """The same bytes as a file (launcher ``weights:``, trainer ``init_from``): WeightsError,
    which both turn into one line and exit 2 (test/faults covers the command lines)."""
    path = write_crafted_file(tmp_path / "actor.safetensors", blob(1), attack)
    with pytest.raises(WeightsError):
        load_actor_file(path)


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "1e999", "[" * 100_000 + "]" * 100_000,
                                     "9" * 5000])
def test_crafted_sidecar_is_a_weights_error(tmp_path: Path, literal: str) -> None:
    path = tmp_path / "actor.safetensors"
    save_actor_file(path, blob(1))
    text = path.with_suffix(".json").read_text().replace('"version": 1', f'"version": {literal}')
    path.with_suffix(".json").write_text(text)
    with pytest.raises(WeightsError, match="sidecar"):
        load_actor_file(path)


def test_fuzzed_payloads_are_accepted_valid_or_counted_drops() -> None:
    """Seeded random and structured mutations of a valid payload through the actor core: each
    is either accepted (and then decodes to finite tensors of the spec's shapes, and the core
    acts on it) or raises WeightsError (what the actor node counts and logs once per kind);
    the core acts after every one of them."""
    base, known = blob(1), blob(2)
    core = ActorCore(robot_id=0, num_robots=1, greedy=False, seed=0,
                     runtime=ActorRuntime.from_weights(known))
    outcomes: Counter[str] = Counter()
    for i, case in enumerate(mutations(base, seed=20261202, count=3000)):
        try:
            accepted = core.offer_weights(base.format, 1, case.payload, case.sha256)
        except WeightsError as e:
            outcomes[f"rejected:{e.kind}"] += 1
            accepted = False
        except Exception as e:
            pytest.fail(f"case {i} ({case.kind}) escaped as {type(e).__name__}: {e}")
        if not accepted:
            assert acts(core, i).version == 2, f"case {i} ({case.kind}) changed the weights"
            continue
        outcomes[f"accepted:{case.kind}"] += 1
        spec, tensors = decode_actor(base.format, 1, case.payload, case.sha256)
        validate_tensors(spec, tensors)  # finite, the spec's names, shapes and dtype
        assert acts(core, i, spec.obs_size).version == 1
        # back to the known weights, so the next case is offered against them again
        assert core.offer_weights(known.format, 2, known.payload, known.sha256)
        assert acts(core, i).version == 2
    rejected = sum(n for k, n in outcomes.items() if k.startswith("rejected"))
    assert rejected > 2000, f"the mutations barely reached the checks: {outcomes}"
    print(f"fuzz outcomes: {dict(sorted(outcomes.items()))}")
