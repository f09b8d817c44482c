"""A deaf trainer, seen by the launcher: the simulator plays on while the trainer's counters
(transitions assembled, records pending, drops of every cause) stand still, for
``restart.deaf_trainer_s`` seconds: it hears nothing at all. Both facts come through files (the
simulator's events, the trainer's status file), not DDS, so the watch still sees when DDS
delivery to the trainer has failed.

Why (docs/reliability.md): a trainer restarted after a SIGKILL next to a running team now and
then (1 of 98 restarts on the default transport, 2 of 57 on UDP alone; Fast DDS 2.14.5, 7 Dec
2026) receives nothing on some or all of its step topics, for good, while its executor runs and
the loop steps at hundreds of steps per second. Re-creating its subscriptions does not bring the
messages back. A new process, with a new DDS participant, is the recovery the launcher can give:
under ``restart.policy: on-failure`` it SIGKILLs the deaf trainer, and the restart path (resume
from the newest checkpoint) starts a fresh one.

A trainer that hears the team changes those counters with every message: a step becomes a
transition or a counted drop at most ``STEP_DEPTH`` steps after it was played, so ``MIN_STEPS``
played steps with no change is no lag. A trainer that hears but cannot learn (a robot's actions
missing, an actor deactivated) counts drops, so it is not deaf: only total silence is, the case
seen on the default transport. The clock restarts whenever the counters change, and with every
new trainer process.

    watch = TrainerWatch(timeout=60.0)
    deaf = watch.observe(now, pid, counters, sim_steps)   # seconds deaf, or None
"""

from __future__ import annotations

from collections.abc import Hashable

# Steps the simulator must play in the window before silence counts: twice the trainer's settle
# window (sdhn_base.ros.qos.STEP_DEPTH, 256: a step is a transition or a drop at most that many
# steps after it was played). Written out, not imported: qos imports rclpy, and the launcher
# runs without it (a test holds the two equal).
MIN_STEPS = 512


class TrainerWatch:
    """Whether the trainer's counters have stood still for ``timeout`` seconds while the
    simulator played at least ``min_steps`` steps (0 turns the watch off)."""

    def __init__(self, timeout: float, min_steps: int = MIN_STEPS) -> None:
        if not timeout >= 0:
            raise ValueError(f"restart.deaf_trainer_s: got {timeout!r}; allowed: seconds >= 0")
        self.timeout = timeout
        self.min_steps = min_steps
        self._pid: int | None = None
        self._counters: Hashable = None
        self._since = 0.0
        self._steps_at = 0

    def observe(self, now: float, pid: int | None, counters: Hashable,
                sim_steps: int) -> float | None:
        """The trainer process now (its pid, and what its status file counts, e.g. (transitions,
        pending, drops); None where there is no process or no status yet) and the steps the
        simulator has played so far -> the seconds it has been deaf when that is past
        ``timeout``, else None."""
        if pid != self._pid or counters is None or counters != self._counters:
            self._pid, self._counters = pid, counters
            self._since, self._steps_at = now, sim_steps
            return None
        silent = now - self._since
        if (self.timeout > 0 and silent >= self.timeout
                and sim_steps - self._steps_at >= self.min_steps):
            return silent
        return None

    def steps_since(self, sim_steps: int) -> int:
        """Steps the simulator played since the counters last changed (for the message)."""
        return sim_steps - self._steps_at
