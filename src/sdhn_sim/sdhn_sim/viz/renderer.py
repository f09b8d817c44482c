"""The stateful viz renderer: team messages in order in, Foxglove scenes, images and metrics out.

Used the same way live (the viz node) and offline (replay, recordings with viz channels).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

from foxglove.messages import RawImage, SceneUpdate

from sdhn_base.drops import DropKind
from sdhn_base.ros.topics import VIZ_EPISODES, VIZ_HYPERGRAPH, VIZ_METRICS, VIZ_P_H, VIZ_SCENE
from sdhn_sim.episode import EpisodeResult
from sdhn_sim.viz.draw import hypergraph_entities, p_h_image, robot_entities, static_entities
from sdhn_sim.viz.world import (
    BadInput,
    HyperFrame,
    IntArray,
    MaifMap,
    MapEstimate,
    TeamFrame,
    parse_hypergraph,
    parse_team_state,
)


# ----------------------------------------------------------------------------- stateful renderer
@dataclass
class _Metrics:
    rate_times: deque[float] = field(default_factory=lambda: deque(maxlen=64))
    return_so_far: float = 0.0
    episode: int = -1
    last_return: float | None = None
    last_makespan: int | None = None
    last_collisions: int | None = None
    episodes_done: int = 0
    policy_version: int = 0
    skewness: float | None = None


class VizRenderer:
    """Keeps what drawing needs across messages (trail, last positions, map, metrics).

    Live (viz node) and offline (replay) use it the same way: call ``on_state`` /
    ``on_hypergraph`` / ``on_episode`` for every message in order (cheap bookkeeping; raise
    ``BadInput``), then build only the outputs somebody wants with ``scene``, ``hypergraph_scene``,
    ``p_h_image``, ``metrics``. ``render`` does both for replay.
    """

    def __init__(self, env: str = "", trail_length: int = 12) -> None:
        self.env = env
        self.trail: deque[IntArray] = deque(maxlen=max(1, trail_length))
        self.frame: TeamFrame | None = None
        self.hyper: HyperFrame | None = None
        self._mapper: MaifMap | None = None
        self._m = _Metrics()
        self.dropped = 0

    # -- bookkeeping (every message)
    def on_state(self, msg: Any, now_s: float | None = None) -> TeamFrame:
        frame = parse_team_state(msg, self.env)
        prev = self.frame
        if prev is None or prev.episode != frame.episode or frame.step < prev.step:
            self.trail.clear()
            self._m.return_so_far = 0.0
        if prev is None or prev.env_name != frame.env_name:
            cfg = frame.world.maif
            self._mapper = MaifMap(cfg) if cfg is not None else None
        self.trail.append(frame.positions)
        if frame.step > 0:
            self._m.return_so_far += frame.team_reward
        self._m.episode = frame.episode
        self._m.rate_times.append(frame.stamp_ns / 1e9 if now_s is None else now_s)
        self.frame = frame
        return frame

    def on_hypergraph(self, msg: Any) -> HyperFrame:
        n = self.frame.world.num_robots if self.frame is not None else None
        hf = parse_hypergraph(msg, n)
        self.hyper = hf
        self._m.skewness = hf.skewness
        self._m.policy_version = max(self._m.policy_version, hf.policy_version)
        return hf

    def on_episode(self, msg: Any) -> dict[str, Any]:
        name = str(msg.env_name)
        if self.env and name != self.env:
            raise BadInput(
                DropKind.ENV_MISMATCH, f"episode of {name!r} but this viewer draws {self.env!r}"
            )
        r = EpisodeResult.from_message(msg)
        # the JSON the episode channel serves: the result's fields, the name as "env"
        out: dict[str, Any] = {"env": r.env_name, **r.to_event()}
        del out["env_name"]
        m = self._m
        m.last_return, m.last_makespan = out["episode_return"], out["makespan"]
        m.last_collisions = out["collisions"]
        m.episodes_done += 1
        m.policy_version = max(m.policy_version, out["policy_version"])
        return out

    # -- outputs (only when wanted)
    def scene(self, with_static: bool = True) -> SceneUpdate:
        """Robots with labels and trails; with the floor, obstacles/racks and goals if asked."""
        if self.frame is None:
            return SceneUpdate()
        entities = static_entities(self.frame, self._mapper) if with_static else []
        entities += robot_entities(self.frame, self.trail)
        return SceneUpdate(entities=entities)

    def map_estimate(self) -> MapEstimate | None:
        if self.frame is None or self._mapper is None:
            return None
        return self._mapper.estimate(self.frame)

    def hypergraph_scene(self) -> SceneUpdate | None:
        """Hyperedges between the robots' latest positions; None before both are known."""
        if self.hyper is None or self.frame is None:
            return None
        if self.hyper.num_robots != self.frame.positions.shape[0]:
            return None
        return SceneUpdate(entities=hypergraph_entities(self.hyper, self.frame.positions))

    def p_h_image(self, cell_px: int = 12) -> RawImage | None:
        return None if self.hyper is None else p_h_image(self.hyper, cell_px)

    def metrics(self) -> dict[str, Any]:
        m, f = self._m, self.frame
        times = m.rate_times
        span = times[-1] - times[0] if len(times) > 1 else 0.0
        return {
            "env": f.env_name if f else self.env,
            "episode": f.episode if f else 0,
            "step": f.step if f else 0,
            "step_rate": (len(times) - 1) / span if span > 0 else 0.0,
            "team_reward": f.team_reward if f else 0.0,
            "return_so_far": m.return_so_far,
            "makespan_so_far": f.makespan_so_far if f else 0,
            "missed_actions": f.missed_actions if f else 0,
            "last_return": m.last_return,
            "last_makespan": m.last_makespan,
            "last_collisions": m.last_collisions,
            "episodes_done": m.episodes_done,
            "policy_version": m.policy_version,
            "skewness": m.skewness,
            "dropped": self.dropped,
        }

    def render(self, kind: str, msg: Any) -> list[tuple[str, Any]]:
        """For replay: feed one recorded message (``kind`` = state | hypergraph | episode) and get
        every viz message it produces as (topic, message); Foxglove messages have ``.encode()``
        and ``get_schema()``, dicts are JSON (schemas ``METRICS_SCHEMA``/``EPISODE_SCHEMA``)."""
        if kind == "state":
            self.on_state(msg)
            return [(VIZ_SCENE, self.scene()), (VIZ_METRICS, self.metrics())]
        if kind == "hypergraph":
            self.on_hypergraph(msg)
            out: list[tuple[str, Any]] = []
            scene = self.hypergraph_scene()
            if scene is not None:
                out.append((VIZ_HYPERGRAPH, scene))
            out.append((VIZ_P_H, self.p_h_image()))
            return out
        if kind == "episode":
            return [(VIZ_EPISODES, self.on_episode(msg))]
        raise ValueError(f"kind must be state, hypergraph or episode, got {kind!r}")

