"""One finished episode: the one type every boundary converts to and from.

An episode result crosses four boundaries, each with its own encoding, and this module holds
every conversion so that the rules live in one place:

- ``sdhn_msgs/EpisodeSummary`` (``to_message`` / ``from_message``): the message has no null, so
  ``makespan`` is 0 there when the episode did not complete; here it is ``None`` (NC).
- the simulator's events file, ``sim-events.jsonl`` (``to_event`` / ``from_event``): the fields
  as JSON, ``makespan`` ``null`` when not completed.
- a row of the launcher's ``episodes.csv`` (``to_csv_row`` / ``from_csv_row``): ``makespan``
  ``"NC"`` when not completed, the return with 3 decimals; the row holds neither the environment
  name nor the formation error.
- the environments' :class:`~sdhn_sim.envs.api.EpisodeStats` (``from_stats`` / ``to_stats``),
  which the in-process metrics (``episode_metrics``) read.

This module imports neither rclpy nor the message package: ``to_message`` fills the message
object it is given, so every layer above ``sdhn_sim`` can use it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from sdhn_sim.envs.api import EpisodeStats

# episodes.csv: the outcome first (completed, makespan), the return second, then the rest.
CSV_FIELDS = ["episode", "completed", "makespan", "return", "length", "collisions",
              "missed_actions", "policy_version", "instance_id", "wall_s", "failed_robots",
              "survivors_completed", "survivors_makespan"]
NOT_COMPLETED = "NC"  # how the CSV row and the logs write a makespan of an uncompleted episode

Msg = TypeVar("Msg")


@dataclass(frozen=True)
class EpisodeResult:
    """Metrics of one finished episode of one deployed (or replayed) environment."""

    env_name: str
    episode: int  # the simulator's episode counter
    length: int  # steps taken
    completed: bool  # every robot reached its goal before the step limit
    makespan: int | None  # steps until completion; None = not completed (NC)
    episode_return: float  # team reward summed over the episode
    # None = unknown: an episode recomputed from recorded TeamStates, or read from a CSV row,
    # which carry neither
    collisions: int | None
    formation_error: float | None
    missed_actions: int  # actions that missed the deadline and became 'stay'
    policy_version: int  # newest policy version seen in this episode's actions
    instance_id: int = -1  # MAIF instance played; -1 without numbered instances (RWARE, old)
    # Robot failure (sdhn_sim.envs.conditions: drawn, or a silent robot over ROS): robots failed
    # by the end, and the survivors' success (every robot not failed on its goal; the failed
    # robots' goals dropped) with its makespan. Without a failure they equal the team's.
    # EpisodeSummary has no field for them: the events file and episodes.csv carry them.
    failed_robots: int = 0
    survivors_completed: bool | None = None  # None = as ``completed`` (no failure known)
    survivors_makespan: int | None = None

    def __post_init__(self) -> None:
        if self.completed != (self.makespan is not None):
            raise ValueError(f"episode {self.episode}: makespan {self.makespan} disagrees with "
                             f"completed={self.completed} (a makespan only when completed)")

    @property
    def survivors_success(self) -> bool:
        """The survivors' success (the team's when no robot failed)."""
        return self.completed if self.survivors_completed is None else self.survivors_completed

    @property
    def makespan_text(self) -> str:
        """The makespan as the logs and tables write it: a number, or NC."""
        return str(self.makespan) if self.makespan is not None else NOT_COMPLETED

    # --- the environments' per-episode statistics ------------------------------------------

    @classmethod
    def from_stats(cls, ep: EpisodeStats, *, env_name: str, episode: int, missed_actions: int,
                   policy_version: int, instance_id: int) -> EpisodeResult:
        return cls(env_name=env_name, episode=episode, length=int(ep.length),
                   completed=bool(ep.completed),
                   makespan=int(ep.makespan) if ep.completed and ep.makespan is not None
                   else None,
                   episode_return=float(ep.episode_return), collisions=int(ep.collisions),
                   formation_error=float(ep.formation_error), missed_actions=int(missed_actions),
                   policy_version=int(policy_version), instance_id=int(instance_id))

    def to_stats(self, env_index: int = 0) -> EpisodeStats:
        return EpisodeStats(env_index=env_index, episode_return=self.episode_return,
                            length=self.length, makespan=self.makespan, completed=self.completed,
                            collisions=self.collisions or 0,
                            formation_error=self.formation_error or 0.0)

    # --- sdhn_msgs/EpisodeSummary -----------------------------------------------------------

    def to_message(self, msg: Msg) -> Msg:
        """Fill an ``EpisodeSummary`` (its header is the caller's): makespan 0 when NC."""
        if self.collisions is None or self.formation_error is None:
            raise ValueError(f"episode {self.episode}: collisions/formation_error unknown, "
                             "cannot fill an EpisodeSummary")
        m: Any = msg
        m.env_name, m.episode, m.length = self.env_name, self.episode, self.length
        m.completed, m.makespan = self.completed, self.makespan or 0
        m.episode_return, m.collisions = self.episode_return, self.collisions
        m.formation_error, m.missed_actions = self.formation_error, self.missed_actions
        m.policy_version, m.instance_id = self.policy_version, self.instance_id
        return msg

    @classmethod
    def from_message(cls, m: Any) -> EpisodeResult:
        """From an ``EpisodeSummary`` (decoded live or from a recording; ``instance_id`` is -1 in
        recordings made before the field)."""
        completed = bool(m.completed)
        return cls(env_name=str(m.env_name), episode=int(m.episode), length=int(m.length),
                   completed=completed, makespan=int(m.makespan) if completed else None,
                   episode_return=float(m.episode_return), collisions=int(m.collisions),
                   formation_error=float(m.formation_error),
                   missed_actions=int(m.missed_actions), policy_version=int(m.policy_version),
                   instance_id=int(getattr(m, "instance_id", -1)))

    # --- the simulator's events file (JSON) -------------------------------------------------

    def to_event(self) -> dict[str, Any]:
        """The fields as the ``episode`` event of ``sim-events.jsonl`` holds them."""
        return dataclasses.asdict(self)

    @classmethod
    def from_event(cls, event: Mapping[str, Any]) -> EpisodeResult:
        """From an ``episode`` event (extra keys such as ``event`` and ``t`` are ignored; the
        optional counts default as an older simulator left them out)."""
        completed = bool(event.get("completed"))
        makespan = event.get("makespan")
        collisions = event.get("collisions", 0)
        formation = event.get("formation_error", 0.0)
        return cls(env_name=str(event.get("env_name", "")), episode=int(event["episode"]),
                   length=int(event["length"]), completed=completed,
                   makespan=int(makespan) if completed and makespan is not None else None,
                   episode_return=float(event["episode_return"]),
                   collisions=None if collisions is None else int(collisions),
                   formation_error=None if formation is None else float(formation),
                   missed_actions=int(event.get("missed_actions", 0)),
                   policy_version=int(event.get("policy_version", 0)),
                   instance_id=int(event.get("instance_id", -1)),
                   failed_robots=int(event.get("failed_robots") or 0),
                   survivors_completed=_opt_bool(event.get("survivors_completed")),
                   survivors_makespan=_opt_int(event.get("survivors_makespan")))

    # --- episodes.csv -------------------------------------------------------------------------

    def to_csv_row(self, wall_s: float) -> dict[str, Any]:
        """One ``episodes.csv`` row (``CSV_FIELDS``); ``wall_s`` = seconds since the launch."""
        return {"episode": self.episode, "completed": self.completed,
                "makespan": self.makespan_text, "return": f"{self.episode_return:.3f}",
                "length": self.length,
                "collisions": self.collisions if self.collisions is not None else "",
                "missed_actions": self.missed_actions, "policy_version": self.policy_version,
                "instance_id": self.instance_id, "wall_s": f"{wall_s:.2f}",
                # empty where no failure is known (the survivors' figures are the team's)
                "failed_robots": self.failed_robots,
                "survivors_completed": "" if self.survivors_completed is None
                else self.survivors_completed,
                "survivors_makespan": "" if self.survivors_completed is None
                else self.survivors_makespan or NOT_COMPLETED}

    @classmethod
    def from_csv_row(cls, row: Mapping[str, str], env_name: str = "") -> EpisodeResult:
        """From a row as ``csv.DictReader`` reads it (columns after ``length`` may be missing in
        hand-made files); the environment name is not in the row: pass it when known."""
        completed = row["completed"].strip().lower() in ("true", "1", "yes")
        collisions = row.get("collisions") or ""
        return cls(env_name=env_name, episode=int(row["episode"]), length=int(row["length"]),
                   completed=completed,
                   makespan=int(row["makespan"]) if completed else None,
                   episode_return=float(row["return"]),
                   collisions=int(collisions) if collisions else None, formation_error=None,
                   missed_actions=int(row.get("missed_actions") or 0),
                   policy_version=int(row.get("policy_version") or 0),
                   instance_id=int(row.get("instance_id") or -1),
                   failed_robots=int(row.get("failed_robots") or 0),
                   survivors_completed=_opt_bool(row.get("survivors_completed")),
                   survivors_makespan=_opt_int(row.get("survivors_makespan")))


def _opt_bool(v: Any) -> bool | None:
    if v is None or v == "":
        return None
    if isinstance(v, str):
        return v.strip().lower() in ("true", "1", "yes")
    return bool(v)


def _opt_int(v: Any) -> int | None:
    if v is None or v in ("", NOT_COMPLETED):
        return None
    return int(v)
