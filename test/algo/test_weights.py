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
