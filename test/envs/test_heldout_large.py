"""The large held-out set and the procedural training stream: sizes, determinism (a pinned
checksum of a prefix of the set), and disjointness from every set a training run can see."""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest

from sdhn_sim.envs import make_env
from sdhn_sim.envs.maif_instances import (
    MAIF_CONFIGS,
    ProceduralInstances,
    _all_reachable,
    generate_instances,
    heldout_config,
    heldout_large_config,
    large_config,
    procedural_config,
    validation_config,
)
from sdhn_sim.envs.registry import instance_set

# sha256 of the first 3 maps (and their formations) of maif-10's large held-out set: the set is
# regenerated, never shipped, so this pins that every machine regenerates the same one.
MAIF10_PREFIX_SHA256 = "8df60d0adb3ea0139ddb88e07960b691da5bcb2a87f76c3c899e17a2fc30ec5a"


def _sha(obstacles: np.ndarray, starts: np.ndarray, goals: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in (obstacles.astype(bool), starts.astype(np.int64), goals.astype(np.int64)):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def test_generator_seeds_of_every_set_are_pairwise_disjoint() -> None:
    """No two sets of any configuration share a generator seed (a held-out set drawn with a
    training set's seed would be that training set)."""
    seeds: dict[int, str] = {}
    for name, cfg in MAIF_CONFIGS.items():
        for which, c in (("train", cfg), ("heldout", heldout_config(cfg)),
                         ("large", large_config(cfg)),
                         ("heldout_large", heldout_large_config(cfg)),
                         ("validation", validation_config(cfg)),
                         ("procedural", procedural_config(cfg))):
            assert c.instance_seed not in seeds, (name, which, seeds.get(c.instance_seed))
            seeds[c.instance_seed] = f"{name}/{which}"


def test_large_heldout_set_size_and_prefix_checksum() -> None:
    for name in ("maif-tiny", "maif-10", "maif-16", "maif-20"):
        c = heldout_large_config(MAIF_CONFIGS[name])
        assert c.num_instances >= 1000 and c.num_maps >= 200
    cfg = heldout_large_config(MAIF_CONFIGS["maif-10"])
    prefix = generate_instances(dataclasses.replace(cfg, num_maps=3))
    assert _sha(prefix.obstacles, prefix.starts, prefix.goals) == MAIF10_PREFIX_SHA256


def test_no_heldout_map_is_a_training_map() -> None:
    """maif-tiny (12x12, the set where a collision is likeliest): no map of either held-out
    set equals a map of the fixed, the large or the first 2,000 procedural training maps."""
    held = [instance_set("maif-tiny", w) for w in ("heldout", "heldout_large", "validation")]
    held_maps = {m.tobytes() for s in held for m in s.obstacles}  # type: ignore[union-attr]
    for which in ("train", "large"):
        inst = instance_set("maif-tiny", which)
        assert not held_maps & {m.tobytes() for m in inst.obstacles}  # type: ignore[union-attr]
    stream = instance_set("maif-tiny", "procedural")
    assert isinstance(stream, ProceduralInstances)
    assert not held_maps & {stream.instance(k)[0].tobytes() for k in range(2000)}


def test_validation_maps_are_not_heldout_maps() -> None:
    """Deployment settings chosen on the validation set say nothing about the large held-out
    set only if the two share no map (maif-tiny: the likeliest to collide)."""
    val, held = (instance_set("maif-tiny", w) for w in ("validation", "heldout_large"))
    assert val.num_instances == held.num_instances >= 1000
    assert not ({m.tobytes() for m in val.obstacles}  # type: ignore[union-attr]
                & {m.tobytes() for m in held.obstacles})  # type: ignore[union-attr]


def test_procedural_stream_is_deterministic_fresh_and_solvable() -> None:
    a = ProceduralInstances(procedural_config(MAIF_CONFIGS["maif-10"]))
    b = ProceduralInstances(procedural_config(MAIF_CONFIGS["maif-10"]), cache_maps=1)
    maps = set()
    for k in (0, 1, 7, 123_456, 999_999):
        ob, st, gl = a.instance(k)
        ob2, st2, gl2 = b.instance(k)
        np.testing.assert_array_equal(ob, ob2)
        np.testing.assert_array_equal(st, st2)
        np.testing.assert_array_equal(gl, gl2)
        assert _all_reachable(ob, st, gl)
        maps.add(ob.tobytes())
    assert len(maps) == 5
    with pytest.raises(ValueError, match="instance id"):
        a.instance(a.num_instances)


def test_env_trains_on_the_procedural_stream() -> None:
    env = make_env("maif-10", num_envs=4, seed=3, instance_set="procedural")
    env.reset()
    seen = set()
    for _ in range(3):
        for b in range(env.num_envs):
            w = env.world(b)
            seen.add(w.instance_id)
            # the env's padded canvas shows the instance's own map
            np.testing.assert_array_equal(w.obstacles, env.instances.instance(w.instance_id)[0])
        env.reset()
    assert len(seen) == 12  # a fresh map every episode
