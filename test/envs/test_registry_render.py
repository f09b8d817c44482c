"""Registry errors and names; NumPy rendering."""

from __future__ import annotations

import numpy as np
import pytest

from sdhn_sim.envs import BatchedEnv, env_names, make_env, make_single_env, robot_colors
from sdhn_sim.envs.render import OBSTACLE_RGB

from .envs_helpers import scenario


def test_names_and_protocol():
    names = env_names()
    for want in ("maif-tiny", "maif-10", "maif-16", "maif-20", "maif-30", "maif-40",
                 "rware-3", "rware-6", "rware-9"):
        assert want in names
    env = make_env("maif-16", num_envs=2, seed=1)
    assert isinstance(env, BatchedEnv)
    assert (env.num_robots, env.obs_size, env.state_size, env.num_actions, env.max_steps) == (
        16, 57, 16 * 57, 5, 500)


def test_unknown_name_lists_known_names():
    with pytest.raises(ValueError, match="unknown environment 'maif-11'") as err:
        make_env("maif-11")
    assert "maif-10" in str(err.value) and "rware-9" in str(err.value)


@pytest.mark.parametrize(
    ("name", "overrides", "field"),
    [
        ("maif-10", {"size": 3}, "size"),
        ("maif-10", {"instance_order": "sorted"}, "instance_order"),
        ("maif-10", {"instance_ids": [0, 100]}, "instance_ids"),
        ("maif-10", {"max_steps": 0}, "max_steps"),
        ("rware-3", {"size": "huge"}, "size"),
        ("rware-3", {"difficulty": "insane"}, "difficulty"),
        ("rware-3", {"instance_ids": [1]}, "instance_ids"),
        ("rware-3", {"backend": "gym"}, "backend"),
    ],
)
def test_bad_overrides_name_the_field(name, overrides, field):
    with pytest.raises(ValueError, match=field) as err:
        make_env(name, **overrides)
    assert "allowed" in str(err.value) or "must be" in str(err.value)


def test_negative_seed_rejected():
    with pytest.raises(ValueError, match="seed"):
        make_single_env("maif-tiny", seed=-1)


def test_render_colours_robots_goals_and_obstacles():
    env = scenario([(1, 1), (4, 2)], [(6, 6), (7, 7)], obstacles=[(3, 3)])
    c = 5
    img = env.render_rgb(0, cell_px=c)
    assert img.shape == (8 * c, 8 * c, 3) and img.dtype == np.uint8
    colors = robot_colors(2)
    assert not np.array_equal(colors[0], colors[1])
    centre = c // 2
    for i, (x, y) in enumerate([(1, 1), (4, 2)]):
        np.testing.assert_array_equal(img[y * c + centre, x * c + centre], colors[i])
    np.testing.assert_array_equal(img[3 * c + centre, 3 * c + centre], OBSTACLE_RGB)
    goal_px = img[6 * c + centre, 6 * c + centre]
    assert not np.array_equal(goal_px, img[5 * c + centre, 5 * c + centre]), "goal not drawn"
