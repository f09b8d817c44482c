"""Final approach: the last step onto a MAIF goal, and staying there, as a deployment rule
decided by each robot from its own observation only (so it runs unchanged in one actor process
per robot, like stall breaking, which it requires).

- **capture**: a robot exactly one cell from its goal (L1 distance 1 in cells) whose goal cell
  is free in its 7x7 window (window value 0) moves onto it, whatever the policy chose (also on a
  step stall breaking samples);
- **path**: a robot two or more cells from its goal, with the goal inside its window and free,
  that stall breaking does not have sampling this step, takes the first step of a shortest path
  to the goal through the window's free cells (4-connected; among equally short first steps the
  first of up, down, left, right); with no such path it acts as chosen;
- **hold**: a robot on its goal stays (action 0), unless stall breaking has it sampling this
  step: that is how an on-goal robot yields to a blocked neighbour (without stall breaking the
  hold would deadlock corridors, so the rule is only offered with it).

A robot whose goal is outside its window acts as the policy (and stall breaking) chose.

Why (docs/fleets.md, "Why it wanders"): the maif-20 actor, run on maif-100, brings its robots
within a few cells of their goals but fails the last step when the goal lies above or to the left
(out of its training distribution: MAIF's goals lie below and to the right of the starts), paces
a few cells from a free goal inside the settled crowd, and on-goal robots drift off 7 % of steps.
Measured on 7 Dec 2026 (greedy with stall breaking 2,10,2, NumPy runtime, 500-step limit), the
maif-20 actor on maif-100: 0.12 without the rule, 0.93 with capture and hold on the first 100
validation instances, 0.901 with capture and hold and 0.958 with all three on all 1,000 (where
the rule was chosen); 0.946 [0.925, 0.965] with all three on the 1,000-instance large held-out
set (capture and hold: 0.922). On maif-20's own held-out set 1.00 with or without it (makespan
139.3 -> 131.1).

Layout read (``sdhn_sim.envs.maif``; docs/maif.md): own position at obs[0:2] and goal at
obs[4:6], both cell index / (size - 1); the 7x7 window from index ``COORD_FEATURES``, row-major
with row = y, the robot at its centre ``RADIUS * WINDOW + RADIUS``; cells 0 free, 1 obstacle or
outside the grid, 2 another robot. Actions (``ACTION_DELTAS``): 0 stay, 1 up (y - 1), 2 down,
3 left (x - 1), 4 right.

    approach = FinalApproach.for_env("maif-100")      # or FinalApproach(size)
    sample = breaker.update(obs)                      # stall breaking's rows sampling this step
    act = approach.apply(obs, act, sample)            # [rows] actions, rows independent
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sdhn_sim.envs.maif import ACTION_DELTAS, COORD_FEATURES, OBS_SIZE, RADIUS, WINDOW

FREE_CELL = 0.0  # a window cell that is on the grid, no obstacle and no robot
STAY = 0
CENTRE_INDEX = COORD_FEATURES + RADIUS * WINDOW + RADIUS  # the robot's own cell in obs
# the action whose move is (dx, dy), indexed [dx + 1, dy + 1] (-1: no single move does it)
MOVE_OF_OFFSET = np.full((3, 3), -1, dtype=np.int64)
for _a, (_dx, _dy) in enumerate(ACTION_DELTAS):
    MOVE_OF_OFFSET[_dx + 1, _dy + 1] = _a
UNREACHED = WINDOW * WINDOW  # longer than any path inside the window


def window_path_steps(windows: npt.NDArray[np.float32],
                      goals: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """[rows, WINDOW * WINDOW] window cells and [rows, 2] goal offsets (dx, dy) inside the
    window -> [rows] the action of the first step of a shortest path from the centre to the goal
    through free cells (4-connected), the first of up, down, left, right among equally short
    ones; -1 where the goal cell is taken or walled off. The distance to the goal is spread over
    the free cells by relaxation, every row at once (a 7x7 window needs at most 48 rounds)."""
    rows = len(windows)
    # padded by one blocked cell on each side, so the four shifted views need no bounds checks
    free = np.zeros((rows, WINDOW + 2, WINDOW + 2), dtype=bool)
    free[:, 1:-1, 1:-1] = windows.reshape(rows, WINDOW, WINDOW) == FREE_CELL
    dist = np.full(free.shape, UNREACHED, dtype=np.int64)
    gx, gy = goals[:, 0] + RADIUS + 1, goals[:, 1] + RADIUS + 1
    r = np.arange(rows)
    dist[r, gy, gx] = np.where(free[r, gy, gx], 0, UNREACHED)
    for _ in range(WINDOW * WINDOW):
        near = np.minimum(np.minimum(dist[:, :-2, 1:-1], dist[:, 2:, 1:-1]),
                          np.minimum(dist[:, 1:-1, :-2], dist[:, 1:-1, 2:])) + 1
        inner = np.where(free[:, 1:-1, 1:-1], np.minimum(dist[:, 1:-1, 1:-1], near), UNREACHED)
        if np.array_equal(inner, dist[:, 1:-1, 1:-1]):
            break
        dist[:, 1:-1, 1:-1] = inner
    c = RADIUS + 1
    here = dist[:, c, c]
    step = np.full(rows, -1, dtype=np.int64)
    for a in (4, 3, 2, 1):  # right, left, down, up: the earliest action written last wins
        dx, dy = ACTION_DELTAS[a]
        on_path = (here < UNREACHED) & (dist[:, c + dy, c + dx] == here - 1)
        step = np.where(on_path, a, step)
    return step


class FinalApproach:
    """The capture, hold and path rule for a MAIF grid of ``size`` x ``size`` cells (see the module
    docstring); stateless, so one instance serves any number of rows."""

    def __init__(self, size: int) -> None:
        if isinstance(size, bool) or not isinstance(size, int) or size < 2:
            raise ValueError(f"final approach: grid size {size!r}; allowed: an integer >= 2")
        self.size = size

    @classmethod
    def for_env(cls, env: str) -> FinalApproach:
        """The rule for a named MAIF task (its grid size); ValueError for any other name (RWARE's
        observations have no goal offset or obstacle window to read)."""
        from sdhn_sim.envs.maif_instances import MAIF_CONFIGS

        if env not in MAIF_CONFIGS:
            raise ValueError(f"final approach reads MAIF observations: env {env!r} is not a MAIF "
                             f"grid; allowed: one of {', '.join(MAIF_CONFIGS)}")
        return cls(MAIF_CONFIGS[env].size)

    def offsets(self, obs: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """[rows, 57] observations -> [rows, 2] goal offset (dx, dy) in cells."""
        o = np.asarray(obs, dtype=np.float32)
        return np.rint((o[:, 4:6] - o[:, 0:2]) * (self.size - 1)).astype(np.int64)

    def apply(self, obs: npt.ArrayLike, act: npt.ArrayLike,
              sampling: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """[rows, 57] observations, [rows] actions chosen (after stall breaking), [rows] bool:
        stall breaking samples the row this step -> [rows] actions with the rule applied."""
        o = np.asarray(obs, dtype=np.float32)
        a = np.asarray(act, dtype=np.int64)
        s = np.asarray(sampling, dtype=bool)
        rows = o.shape[0] if o.ndim == 2 else -1
        if o.ndim != 2 or o.shape[1] != OBS_SIZE or a.shape != (rows,) or s.shape != (rows,):
            raise ValueError(f"final approach: expected obs [rows, {OBS_SIZE}], act and sampling "
                             f"[rows]; got {list(o.shape)}, {list(a.shape)}, {list(s.shape)}")
        d = self.offsets(o)
        dist = np.abs(d).sum(axis=1)
        one = dist == 1
        out = a.copy()
        if one.any():
            r = np.flatnonzero(one)
            dx, dy = d[r, 0], d[r, 1]
            goal_free = o[r, CENTRE_INDEX + dx + dy * WINDOW] == FREE_CELL
            out[r[goal_free]] = MOVE_OF_OFFSET[dx + 1, dy + 1][goal_free]
        out[(dist == 0) & ~s] = STAY
        path = (dist >= 2) & (np.abs(d).max(axis=1) <= RADIUS) & ~s
        if path.any():
            r = np.flatnonzero(path)
            step = window_path_steps(o[r, COORD_FEATURES:], d[r])
            out[r[step >= 0]] = step[step >= 0]
        return out
