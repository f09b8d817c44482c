"""The kinds of dropped input, one enumeration for every node and status file.

A node that drops a message (or a step, or a rollout) counts it under one of these kinds, logs it
once per kind, and writes the counts to its status file (``sdhn_base.ros.status``) keyed by the
kind's value. The values are stable snake_case names: supervisors, scripts and tests read them.
``DropKind`` is a ``StrEnum``, so a member is its value wherever a string is expected (a dict
key, JSON, an f-string).
"""

from __future__ import annotations

from enum import StrEnum


class DropKind(StrEnum):
    """Why an input was dropped; the value is the key in status files."""

    # messages that cannot be read at all
    UNDECODABLE = "undecodable"
    NOT_STARTED = "not_started"  # an action before step 0 or after the last episode
    # which environment (viewers)
    UNKNOWN_ENV = "unknown_env"
    ENV_MISMATCH = "env_mismatch"  # a message of another environment than the one drawn
    # whose robot
    UNKNOWN_ROBOT = "unknown_robot"  # robot id outside 0..N-1
    WRONG_ROBOT = "wrong_robot"  # robot id differs from the topic's (or the actor's) robot
    WRONG_TEAM_SIZE = "wrong_team_size"  # num_robots differs from the team's
    # when
    STALE_STEP = "stale_step"  # (episode, step) already taken, assembled or dropped
    FUTURE_STEP = "future_step"  # (episode, step) skips ahead or beyond the step limit
    DUPLICATE_OBS = "duplicate_obs"
    DUPLICATE_ACTION = "duplicate_action"
    DUPLICATE_STATE = "duplicate_state"
    # what
    WRONG_OBS_LENGTH = "wrong_obs_length"
    WRONG_STATE_LENGTH = "wrong_state_length"
    WRONG_SIZE = "wrong_size"  # another array (positions, P_H, incidence) of the wrong size
    OUT_OF_GRID = "out_of_grid"  # a position outside the map
    BAD_VALUE = "bad_value"  # P_H outside [0, 1], a skewness not finite
    NON_FINITE_OBS = "non_finite_obs"
    BAD_OBS_AGE = "bad_obs_age"  # dead reckoning: obs_age missing, or older than the episode
    NON_FINITE_STATE = "non_finite_state"
    ACTION_OUT_OF_RANGE = "action_out_of_range"
    BAD_LOG_PROB = "bad_log_prob"  # log-prob not finite or > 0
    NON_FINITE_LOGITS = "non_finite_logits"  # the policy computed NaN/Inf logits: no action
    BAD_POLICY_OUTPUT = "bad_policy_output"  # the policy's outputs break its contract (shape)
    # policy weights (actors)
    NO_WEIGHTS = "no_weights"  # an observation arrived before any policy weights
    UNKNOWN_FORMAT = "unknown_format"
    BAD_SHA256 = "bad_sha256"
    BAD_TENSORS = "bad_tensors"
    OVERSIZED_PAYLOAD = "oversized_payload"
    BAD_WEIGHTS = "bad_weights"  # any other unreadable weights
    INCOMPATIBLE_WEIGHTS = "incompatible_weights"  # weights for another observation/action size
    # steps and rollouts the trainer could not learn from
    MISSED_ACTION = "missed_action"  # a step where the simulator made a robot 'stay'
    INCOMPLETE_STEP = "incomplete_step"  # missing obs, action or state once settled
    STEP_NEVER_SEEN = "step_never_seen"  # none of the step's messages arrived
    LEARNER_BUSY = "learner_busy"  # a rollout dropped because the learner offload was full
    PAST_TOTAL_STEPS = "past_total_steps"  # a rollout after total_steps (not learned)

    def __repr__(self) -> str:
        # Counts are logged as dicts ({'stale_step': 2}), and supervisors and tests read those
        # lines: a kind prints as its value there too, never as <DropKind.STALE_STEP: ...>.
        return repr(self.value)


DESCRIPTIONS: dict[DropKind, str] = {
    DropKind.UNDECODABLE: "undecodable CDR",
    DropKind.NOT_STARTED: "action before step 0 or after the end",
    DropKind.UNKNOWN_ENV: "unknown environment",
    DropKind.ENV_MISMATCH: "another environment than the one drawn",
    DropKind.UNKNOWN_ROBOT: "unknown robot id",
    DropKind.WRONG_ROBOT: "robot id differs from the topic's robot",
    DropKind.WRONG_TEAM_SIZE: "wrong num_robots",
    DropKind.STALE_STEP: "stale step (already taken, assembled or dropped)",
    DropKind.FUTURE_STEP: "future step (skips ahead or beyond the step limit)",
    DropKind.DUPLICATE_OBS: "duplicate observation",
    DropKind.DUPLICATE_ACTION: "duplicate action",
    DropKind.DUPLICATE_STATE: "duplicate state",
    DropKind.WRONG_OBS_LENGTH: "wrong observation length",
    DropKind.WRONG_STATE_LENGTH: "wrong state length",
    DropKind.WRONG_SIZE: "array of the wrong size",
    DropKind.OUT_OF_GRID: "position outside the map",
    DropKind.BAD_VALUE: "value out of range or not finite",
    DropKind.NON_FINITE_OBS: "NaN/Inf in an observation",
    DropKind.BAD_OBS_AGE: "observation age missing or before the episode's start (dead "
                          "reckoning)",
    DropKind.NON_FINITE_STATE: "NaN/Inf in a state",
    DropKind.ACTION_OUT_OF_RANGE: "action out of range",
    DropKind.BAD_LOG_PROB: "log_prob not finite or > 0",
    DropKind.NON_FINITE_LOGITS: "NaN/Inf logits from the policy (no action sent)",
    DropKind.BAD_POLICY_OUTPUT: "policy outputs of the wrong shape or type (no action sent)",
    DropKind.NO_WEIGHTS: "no policy weights yet",
    DropKind.UNKNOWN_FORMAT: "unknown weights format",
    DropKind.BAD_SHA256: "weights sha256 mismatch",
    DropKind.BAD_TENSORS: "weights tensors unreadable or of the wrong shape",
    DropKind.OVERSIZED_PAYLOAD: "weights payload larger than an actor accepts",
    DropKind.BAD_WEIGHTS: "unreadable weights",
    DropKind.INCOMPATIBLE_WEIGHTS: "weights that do not fit this actor",
    DropKind.MISSED_ACTION: "step with a missed action (the simulator made a robot 'stay')",
    DropKind.INCOMPLETE_STEP: "incomplete step (missing obs, action or state)",
    DropKind.STEP_NEVER_SEEN: "step never seen (none of its messages arrived)",
    DropKind.LEARNER_BUSY: "rollout dropped (learner offload busy)",
    DropKind.PAST_TOTAL_STEPS: "rollout after total_steps (not learned)",
}


def describe(kind: str) -> str:
    """``kind (what it means)`` for a log line; an unknown kind is returned as it is."""
    try:
        return f"{kind} ({DESCRIPTIONS[DropKind(kind)]})"
    except ValueError:
        return kind
