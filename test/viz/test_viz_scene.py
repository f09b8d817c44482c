"""sdhn_sim.viz without ROS: the map from the instance id, validation, scenes decoded as Foxglove
would (protobuf)."""

from __future__ import annotations

import array
import json
import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from sdhn_base.ros.topics import VIZ_EPISODES, VIZ_HYPERGRAPH, VIZ_METRICS, VIZ_P_H, VIZ_SCENE
from sdhn_sim.envs import load_instances, make_single_env
from sdhn_sim.viz.draw import cell_center, map_to_cell
from sdhn_sim.viz.renderer import VizRenderer
from sdhn_sim.viz.world import BadInput, MaifMap, parse_team_state, world_info


def decode(message: Any) -> Any:
    """Decode a foxglove message object with the FileDescriptorSet the SDK advertises for it."""
    schema = message.get_schema()
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
    return cls.FromString(message.encode())


def stamp() -> SimpleNamespace:
    return SimpleNamespace(stamp=SimpleNamespace(sec=12, nanosec=34))


def team_state(env_name: str, state: np.ndarray, positions: np.ndarray, **kw: Any) -> Any:
    fields = dict(
        header=stamp(), env_name=env_name, episode=0, step=0,
        num_robots=positions.shape[0], state=array.array("f", state.astype(np.float32).tobytes()),
        positions=positions.reshape(-1).tolist(), team_reward=0.0, terminated=False,
        truncated=False, makespan_so_far=0, missed_actions=0, instance_id=-1,
    )
    fields.update(kw)
    return SimpleNamespace(**fields)


def maif_msg(name: str = "maif-tiny", seed: int = 0, **kw: Any) -> tuple[Any, Any]:
    env = make_single_env(name, seed=seed)
    _, state = env.reset()
    kw.setdefault("instance_id", env.instance_id)
    return team_state(name, state, env.positions, **kw), env


def entities(update: Any) -> dict[str, Any]:
    return {e.id: e for e in decode(update).entities}


def test_cell_and_map_coordinates_round_trip() -> None:
    for x, y in [(0, 0), (3, 7), (31, 31)]:
        mx, my = cell_center(x, y)
        assert map_to_cell(mx, my) == (x, y)
    assert cell_center(0, 0) == (0.5, -0.5)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_maif_map_is_the_instance_the_state_names(seed: int) -> None:
    msg, env = maif_msg("maif-tiny", seed)
    renderer = VizRenderer()
    renderer.on_state(msg)
    est = renderer.map_estimate()
    assert est is not None and est.exact
    assert est.instance_id == int(env.env.instance_id[0])
    assert np.array_equal(est.obstacles, env.obstacles)


@pytest.mark.parametrize("instance", ["none", "contradicted"])
def test_maif_without_a_usable_id_shows_only_what_windows_show(instance: str) -> None:
    """No id (a recording made before TeamState carried one) or an id whose map the robots'
    windows contradict: the map is what the windows showed, never a guessed instance."""
    msg, env = maif_msg("maif-tiny", 0)
    if instance == "none":
        msg.instance_id = -1
    else:
        cfg = world_info("maif-tiny").maif
        assert cfg is not None
        state = np.frombuffer(msg.state, np.float32).reshape(4, -1)
        seen, known = MaifMap(cfg).observed(state, env.positions)
        inst = load_instances("maif-tiny")
        msg.instance_id = next(k for k in range(inst.num_instances)
                               if not np.array_equal(inst.instance(k)[0][known], seen[known]))
    frame = parse_team_state(msg)
    est = MaifMap(frame.world.maif).estimate(frame)  # type: ignore[arg-type]
    assert not est.exact and est.instance_id == -1
    assert 0 < est.known.sum() < est.known.size
    assert np.array_equal(est.obstacles[est.known], env.obstacles[est.known])


def test_scene_has_robots_at_their_cells_with_labels_trails_and_static_map() -> None:
    msg, env = maif_msg("maif-10", 3)
    renderer = VizRenderer(trail_length=4)
    renderer.on_state(msg)
    moved = env.positions.copy()
    renderer.on_state(team_state("maif-10", np.frombuffer(msg.state, np.float32), moved, step=1,
                                 instance_id=msg.instance_id))
    found = entities(renderer.scene())
    assert {"map/floor", "map/obstacles", "map/goals"} <= set(found)
    assert len(found["map/obstacles"].cubes) == int(env.obstacles.sum())
    for i, (x, y) in enumerate(env.positions.tolist()):
        robot = found[f"robot/{i}"]
        assert robot.frame_id == "map"
        p = robot.cubes[0].pose.position
        assert map_to_cell(p.x, p.y) == (x, y)
        assert robot.texts[0].text == str(i)
        assert len(robot.lines[0].points) == 2
    colors = {tuple(round(c, 3) for c in (r.cubes[0].color.r, r.cubes[0].color.g,
                                          r.cubes[0].color.b))
              for k, r in found.items() if k.startswith("robot/")}
    assert len(colors) == 10, "one colour per robot id"
    dynamic = entities(renderer.scene(with_static=False))
    assert not any(k.startswith("map/") for k in dynamic)


def test_trail_restarts_with_a_new_episode() -> None:
    msg, _ = maif_msg("maif-tiny", 0)
    renderer = VizRenderer()
    for step in range(3):
        msg.step = step
        renderer.on_state(msg)
    msg.episode, msg.step = 1, 0
    renderer.on_state(msg)
    assert len(renderer.trail) == 1


@pytest.mark.parametrize(
    "change,kind",
    [
        ({"env_name": "maif-nope"}, "unknown_env"),
        ({"num_robots": 5}, "wrong_team_size"),
        ({"state": array.array("f", [0.0] * 10)}, "wrong_state_length"),
        ({"positions": [0, 0, 1, 1]}, "wrong_size"),
        ({"positions": [0, 0, 1, 1, 2, 2, 12, 3]}, "out_of_grid"),
        ({"state": array.array("f", [math.nan] * 228)}, "non_finite_state"),
    ],
    ids=lambda v: v if isinstance(v, str) else ",".join(v),
)
def test_bad_team_state_is_rejected_by_kind(change: dict[str, Any], kind: str) -> None:
    msg, _ = maif_msg("maif-tiny", 0)
    for key, value in change.items():
        setattr(msg, key, value)
    with pytest.raises(BadInput) as info:
        VizRenderer().on_state(msg)
    assert info.value.kind == kind


def test_state_of_another_env_is_rejected_when_env_is_fixed() -> None:
    msg, _ = maif_msg("maif-tiny", 0)
    with pytest.raises(BadInput, match="env_mismatch"):
        VizRenderer(env="maif-10").on_state(msg)


def hypergraph(n: int, m: int, **kw: Any) -> Any:
    rng = np.random.default_rng(0)
    p_h = rng.random((n, m)).astype(np.float32)
    fields = dict(
        header=stamp(), episode=0, step=0, num_robots=n, num_hyperedges=m,
        p_h=array.array("f", p_h.tobytes()), incidence=(p_h > 0.5).astype(np.uint8).tobytes(),
        skewness=0.25, policy_version=3,
    )
    fields.update(kw)
    return SimpleNamespace(**fields)


def test_hypergraph_scene_and_p_h_heatmap() -> None:
    msg, _ = maif_msg("maif-tiny", 0)
    renderer = VizRenderer()
    renderer.on_state(msg)
    out = dict(renderer.render("hypergraph", hypergraph(4, 3)))
    found = entities(out[VIZ_HYPERGRAPH])
    meta = {kv.key: kv.value for kv in found["hypergraph"].metadata}
    assert meta["skewness"] == "0.2500" and meta["num_hyperedges"] == "3"
    assert {f"hyperedge/{j}" for j in range(3)} <= set(found)
    image = decode(out[VIZ_P_H])
    assert (image.height, image.width, image.encoding) == (4 * 12, 3 * 12, "rgb8")
    assert len(image.data) == image.height * image.step
    assert renderer.metrics()["skewness"] == 0.25


@pytest.mark.parametrize(
    "change",
    [{"p_h": array.array("f", [0.5] * 5)}, {"p_h": array.array("f", [2.0] * 12)},
     {"incidence": b"\x01" * 5}, {"num_robots": 6, "p_h": array.array("f", [0.5] * 18)}],
    ids=["p_h_size", "p_h_range", "incidence_size", "team_size"],
)
def test_bad_hypergraph_is_rejected(change: dict[str, Any]) -> None:
    msg, _ = maif_msg("maif-tiny", 0)
    renderer = VizRenderer()
    renderer.on_state(msg)
    bad = hypergraph(4, 3)
    for key, value in change.items():
        setattr(bad, key, value)
    with pytest.raises(BadInput):
        renderer.on_hypergraph(bad)


def test_metrics_follow_states_and_episodes() -> None:
    msg, _ = maif_msg("maif-tiny", 0)
    renderer = VizRenderer()
    for step in range(4):
        msg.step, msg.team_reward = step, 1.5
        renderer.on_state(msg, now_s=step * 0.1)
    summary = SimpleNamespace(
        env_name="maif-tiny", episode=0, length=9, completed=False, makespan=0,
        episode_return=-3.0, collisions=2, formation_error=0.5, missed_actions=1,
        policy_version=7, instance_id=5,
    )
    (topic, episode), = renderer.render("episode", summary)
    assert topic == VIZ_EPISODES and episode["makespan"] is None and episode["instance_id"] == 5
    m = renderer.metrics()
    assert m["return_so_far"] == pytest.approx(4.5)
    assert m["step_rate"] == pytest.approx(10.0)
    assert m["last_return"] == -3.0 and m["policy_version"] == 7 and m["episodes_done"] == 1
    json.dumps(m)  # a Plot panel gets plain JSON


def test_render_for_replay_gives_scene_and_metrics_per_state() -> None:
    msg, _ = maif_msg("maif-tiny", 0)
    out = VizRenderer().render("state", msg)
    assert [t for t, _ in out] == [VIZ_SCENE, VIZ_METRICS]
    with pytest.raises(ValueError, match="kind"):
        VizRenderer().render("weights", msg)


def test_rware_scene_has_racks_goals_and_robots() -> None:
    env = make_single_env("rware-3", seed=0)
    obs, state = env.reset()
    positions = obs[:, :2].astype(np.int64)
    renderer = VizRenderer()
    renderer.on_state(team_state("rware-3", state, positions))
    found = entities(renderer.scene())
    world = world_info("rware-3")
    assert len(found["map/racks"].cubes) == int(world.rware_racks.sum())  # type: ignore[union-attr]
    assert len(found["map/goals"].cubes) == len(world.rware_goals)
    for i, (x, y) in enumerate(positions.tolist()):
        p = found[f"robot/{i}"].cubes[0].pose.position
        assert map_to_cell(p.x, p.y) == (x, y)
        assert len(found[f"robot/{i}"].arrows) == 1
    assert "shelves/seen" in found
