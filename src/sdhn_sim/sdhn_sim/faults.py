"""A fault schedule: which actor processes die, and when, in a ROS deployment (no ROS here).

A launch file's ``faults:`` block lists the robots whose actor process is killed (SIGKILL, never
restarted) at a chosen step::

    faults:
      - {robot: 3, at_step: 40}               # episode 0 unless given
      - {robot: 5, at_step: 10, episode: 1}

The simulator and the launcher share it (the simulator's ``faults`` parameter holds the same block
as YAML text). The simulator stops sending the robot its observations from the first step at or
after ``(episode, at_step)``, so the robot's last action answers the step before, whatever the
launcher's reaction time, and writes a ``fault`` event; the launcher then kills the process. From
there on the robot is silent, and the simulator finds that out as it would for any dead robot
(``fail_after_missed``; :mod:`sdhn_sim.lockstep`). :func:`parse_faults` validates a block with a
one-line error naming the entry and field.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from sdhn_base.yaml_io import YamlError, load_yaml

FIELDS = ("robot", "at_step", "episode")


class FaultsError(ValueError):
    """An invalid fault schedule; the message names the entry, the field and what is allowed."""


@dataclass(frozen=True, order=True)
class Fault:
    episode: int
    at_step: int
    robot: int

    def to_dict(self) -> dict[str, int]:
        return {"robot": self.robot, "at_step": self.at_step, "episode": self.episode}


def _int(where: str, v: Any, lo: int, hi: int | None = None) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < lo or (hi is not None and v > hi):
        span = f"{lo} .. {hi}" if hi is not None else f">= {lo}"
        raise FaultsError(f"{where}: got {v!r}; allowed: an integer {span}")
    return v


def parse_faults(block: Any, num_robots: int, episodes: int = 0) -> tuple[Fault, ...]:
    """A ``faults:`` block (a list of mappings, its YAML text, or None/''/[] = none) ->
    the faults in time order. ``episodes`` (0 = unlimited) bounds ``episode``. At least one robot
    must stay alive, and a robot dies at most once (a killed actor is never restarted)."""
    if isinstance(block, str):
        try:
            block = load_yaml(block, what="faults") if block.strip() else None
        except YamlError as e:
            raise FaultsError(str(e)) from e
    if block is None:
        return ()
    if not isinstance(block, Sequence) or isinstance(block, str | bytes):
        raise FaultsError(f"faults: got {type(block).__name__}; allowed: a list of "
                          "{robot, at_step[, episode]} mappings")
    out: list[Fault] = []
    for i, entry in enumerate(block):
        where = f"faults[{i}]"
        if not isinstance(entry, dict):
            raise FaultsError(f"{where}: got {entry!r}; allowed: a mapping with robot, at_step "
                              "and optionally episode")
        unknown = [k for k in entry if k not in FIELDS]
        if unknown:
            raise FaultsError(f"{where}.{unknown[0]}: unknown field; allowed: "
                              f"{', '.join(FIELDS)}")
        for key in ("robot", "at_step"):
            if key not in entry:
                raise FaultsError(f"{where}.{key}: missing; allowed: robot, at_step (both "
                                  "needed), episode (default 0)")
        robot = _int(f"{where}.robot", entry["robot"], 0, num_robots - 1)
        at_step = _int(f"{where}.at_step", entry["at_step"], 0)
        episode = _int(f"{where}.episode", entry.get("episode", 0), 0,
                       episodes - 1 if episodes > 0 else None)
        if (episode, at_step) == (0, 0):
            raise FaultsError(f"{where}.at_step: 0 in episode 0; allowed: a later step (a robot "
                              "that never acts is a missing actor, not a failure)")
        if any(f.robot == robot for f in out):
            raise FaultsError(f"{where}.robot: robot {robot} is already in the schedule; "
                              "allowed: each robot once (a killed actor is never restarted)")
        out.append(Fault(episode, at_step, robot))
    if len(out) >= num_robots:
        raise FaultsError(f"faults: {len(out)} of {num_robots} robots; allowed: at most "
                          f"{num_robots - 1} (at least one robot survives)")
    return tuple(sorted(out))


def faults_text(faults: Sequence[Fault]) -> str:
    """The schedule as the simulator's ``faults`` parameter holds it (YAML flow text)."""
    if not faults:
        return ""
    return "[" + ", ".join(f"{{robot: {f.robot}, at_step: {f.at_step}, episode: {f.episode}}}"
                           for f in faults) + "]"
