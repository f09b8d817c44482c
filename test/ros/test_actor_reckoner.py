"""The actor node's dead-reckoning rule, in process over real rclpy: an RWARE actor builds the
warehouse (to read its layout) once at start-up, where it validates ``dead_reckoning``, and
hands that rule to the core it loads; a core loaded again (a managed actor cleaned up and
configured anew) gets it as newly built, nothing of the episode the previous core reckoned."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import rclpy
from rclpy.context import Context

from sdhn_policy.actor_node import ActorNode
from sdhn_policy.dead_reckoning import reckoner_for
from sdhn_sim.envs import registry

ENV = "rware-tiny-2ag"
WEIGHTS = "models/rware-tiny-2ag-mappo/actor.safetensors"


@pytest.fixture
def actor(monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[ActorNode, list[str]]]:
    """An unmanaged rware-tiny-2ag actor with dead reckoning (it loads its core at start), and
    the names of the envs built since just before it started (the real make_env, counted)."""
    built: list[str] = []
    real = registry.make_env

    def counted(name: str, *args: Any, **kwargs: Any) -> Any:
        built.append(name)
        return real(name, *args, **kwargs)

    monkeypatch.setattr(registry, "make_env", counted)
    context = Context()
    rclpy.init(context=context, args=[
        "actor", "--ros-args", "-p", "robot_id:=0", "-p", "num_robots:=2", "-p", f"env:={ENV}",
        "-p", "dead_reckoning:=true", "-p", f"weights_file:={WEIGHTS}", "-p", "greedy:=true",
        "-p", "team_ns:=/sdhn_reckoner_test"])
    node = ActorNode(context)
    try:
        yield node, built
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def state(rule: Any) -> dict[str, Any]:
    """Every array the rule (and its action history) keeps, by name."""
    found = {k: v for k, v in vars(rule).items() if isinstance(v, np.ndarray)}
    return found | {f"history.{k}": v for k, v in vars(rule.history).items()
                    if isinstance(v, np.ndarray)}


def test_the_rware_rule_is_built_once_and_each_core_gets_it_fresh(
        actor: tuple[ActorNode, list[str]]) -> None:
    node, built = actor
    assert built == [ENV], built  # validated and given to the loaded core: one warehouse
    first = node._loaded
    assert first is not None and first.reckoner is node.reckoner
    # The first core plays a few steps under one step of latency: the rule remembers them.
    env = registry.make_env(ENV, num_envs=1, seed=3)
    obs, _ = env.reset()
    for step in range(4):
        first.on_obs(1, step, 0, 2, np.asarray(obs[0][0], dtype=np.float32),
                     obs_age=min(step, 1))
    assert first.reckoned > 0
    fresh = state(reckoner_for(ENV))
    assert any(not np.array_equal(v, fresh[k]) for k, v in state(node.reckoner).items())
    count = len(built)
    second = node.load_core()  # as configure does after a cleanup
    assert len(built) == count  # no new warehouse
    assert second.reckoner is node.reckoner
    got = state(second.reckoner)
    assert got.keys() == fresh.keys()
    for k, v in got.items():
        assert np.array_equal(v, fresh[k]), k
