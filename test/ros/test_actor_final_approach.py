"""The actor node's final approach, in process over real rclpy: ``final_approach:=true`` (with
``break_stalls`` and ``env`` naming the grid) builds the rule for that grid and hands it to every
core it loads; the core then steps onto a free goal one cell away, in any direction (the maif-tiny
policy, trained with goals below and to the right, is not asked), and holds a goal it stands on.
Its configuration errors are one line, exit 2 (test_decentralised)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import rclpy
from rclpy.context import Context

from sdhn_policy.actor_core import Decision
from sdhn_policy.actor_node import ActorNode
from sdhn_sim.envs.maif import COORD_FEATURES, OBS_SIZE, RADIUS, WINDOW

WEIGHTS = "models/maif-tiny-sdhn/actor.safetensors"
SIZE = 12  # maif-tiny's grid


@pytest.fixture
def actor() -> Iterator[ActorNode]:
    context = Context()
    rclpy.init(context=context, args=[
        "actor", "--ros-args", "-p", "robot_id:=0", "-p", "num_robots:=4", "-p", "env:=maif-tiny",
        "-p", "greedy:=true", "-p", "break_stalls:=true", "-p", "final_approach:=true",
        "-p", f"weights_file:={WEIGHTS}", "-p", "team_ns:=/sdhn_final_approach_test"])
    node = ActorNode(context)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def obs(x: int, y: int, gx: int, gy: int, step: int) -> np.ndarray:
    o = np.zeros(OBS_SIZE, dtype=np.float32)
    s = 1.0 / (SIZE - 1)
    o[0:8] = [x * s, y * s, 0.1 * step, 0.5, gx * s, gy * s, 0.5, 0.5]  # the centroid moves
    o[COORD_FEATURES + RADIUS * WINDOW + RADIUS + WINDOW + 1] = 2.0  # a robot below-right
    return o


def test_the_node_steps_onto_free_goals_and_holds_them(actor: ActorNode) -> None:
    assert actor.approach is not None and actor.approach.size == SIZE
    for episode, (goal, move) in enumerate([((5, 4), 4), ((3, 4), 3), ((4, 3), 1),
                                            ((4, 5), 2)]):
        core = actor.load_core()  # as configure does; each core gets the node's rule
        assert core.approach is actor.approach
        first = core.on_obs(episode, 0, 0, 4, obs(4, 4, *goal, 0))
        assert isinstance(first, Decision) and first.action == move, (goal, first)
        on_goal = core.on_obs(episode, 1, 0, 4, obs(*goal, *goal, 1))
        assert isinstance(on_goal, Decision) and on_goal.action == 0, (goal, on_goal)
