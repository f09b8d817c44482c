"""Where an action leads, read from a robot's own observation (sdhn_sim.poses), checked against
the real environments: the predicted target cell is where the robot is after the step whenever
the move was not blocked, in the viewer's map frame."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sdhn_sim.envs import make_single_env
from sdhn_sim.poses import cell_center, target_reader, yaw_quaternion
from sdhn_sim.viz.draw import cell_center as viz_cell_center


def test_cell_centres_are_the_viewers() -> None:
    for x, y in ((0, 0), (3, 7), (19, 2)):
        assert cell_center(x, y) == viz_cell_center(x, y)
    z, w = yaw_quaternion(math.pi / 2)
    assert math.isclose(z * z + w * w, 1.0) and math.isclose(2 * math.atan2(z, w), math.pi / 2)


@pytest.mark.parametrize("env", ["maif-tiny", "maif-10", "rware-3"])
def test_targets_are_where_unblocked_moves_end(env: str) -> None:
    reader = target_reader(env)
    assert reader is not None
    sim = make_single_env(env, seed=4)
    obs, _ = sim.reset()
    rng = np.random.default_rng(0)
    checked = moved = 0
    for _ in range(60):
        actions = rng.integers(0, sim.num_actions, sim.num_robots)
        targets = [reader(obs[i], int(a)) for i, a in enumerate(actions)]
        res = sim.step(actions)
        after = np.asarray(sim.positions).reshape(-1, 2)
        for i, (tx, ty, _yaw) in enumerate(targets):
            here = cell_center(*after[i])
            if here == (tx, ty):
                checked += 1
                moved += int(actions[i]) == 1 if env.startswith("rware") else int(actions[i]) != 0
        obs = res.obs
        if res.terminated or res.truncated:
            obs, _ = sim.reset()
    # most steps are unblocked: the prediction must match there, including real moves
    assert checked >= 0.6 * 60 * sim.num_robots and moved > 10, (checked, moved)


def test_maif_yaw_faces_the_move() -> None:
    reader = target_reader("maif-10")
    assert reader is not None
    obs = np.zeros(57, np.float32)
    obs[0], obs[1] = 4 / 31, 5 / 31  # cell (4, 5) of the 32 x 32 grid
    assert reader(obs, 0) == (4.5, -5.5, 0.0)  # stay
    x, y, yaw = reader(obs, 1)  # up: y - 1, which is +y in the map frame
    assert (x, y) == (4.5, -4.5) and math.isclose(yaw, math.pi / 2)
    assert reader(obs, 4)[:2] == (5.5, -5.5) and reader(obs, 4)[2] == 0.0  # right
    assert target_reader("no-such-env") is None
