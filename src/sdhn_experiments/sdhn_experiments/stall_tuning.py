"""Choosing a stall rule (``sdhn_policy.stall_breaker``) on the validation set, so that the large
held-out set reports it without having been looked at while choosing.

    greedy = evaluate_set(rt, "maif-10", "validation")
    scores = [score(rule, evaluate_set(rt, "maif-10", "validation", stall=rule), greedy)
              for rule in rule_grid()]
    best = choose(scores)

A rule is judged by its success rate and by its **slowdown**: the mean, over the instances both
it and greedy play complete, of its makespan over greedy's on the same instance. The slowdown is
paired with greedy, so a rule that completes more (harder) instances is not charged for them,
and it needs no planner. ``choose`` keeps the rules within ``tolerance`` of the best success
rate (5 of 1,000 instances by default: below what one seed of play can tell apart) and takes the
one with the smallest slowdown, the first in grid order on a tie.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from sdhn_experiments.heldout_eval import InstanceResult
from sdhn_policy.stall_breaker import StallRule

CALM_STEPS = (2, 3, 5)
PROGRESS_STEPS = (3, 5, 10)
SAMPLE_STEPS = (2, 3, 5)
TEMPERATURES = (1.0,)
SUCCESS_TOLERANCE = 0.005


def rule_grid(calm: Sequence[int] = CALM_STEPS, progress: Sequence[int] = PROGRESS_STEPS,
              sample: Sequence[int] = SAMPLE_STEPS,
              temperatures: Sequence[float] = TEMPERATURES) -> list[StallRule]:
    """Every combination, smallest values first (the order ``choose`` breaks ties by)."""
    combos = itertools.product(sorted(set(temperatures), reverse=True), sorted(set(calm)),
                               sorted(set(progress)), sorted(set(sample)))
    return [StallRule(c, p, s, t).check() for t, c, p, s in combos]


@dataclass(frozen=True)
class RuleScore:
    """One rule on one instance set."""

    rule: StallRule
    success_rate: float
    slowdown: float | None  # makespan over greedy's, mean over instances both complete
    paired_instances: int
    deadlocks: int

    def as_json(self) -> dict[str, Any]:
        return {**asdict(self), "rule": self.rule.text()}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RuleScore:
        """The inverse of ``as_json``."""
        return cls(**{**data, "rule": StallRule.parse(data["rule"])})


def score(rule: StallRule, recs: Sequence[InstanceResult],
          greedy: Sequence[InstanceResult]) -> RuleScore:
    """``rule``'s records against greedy play's on the same instances (same order)."""
    if [r.instance for r in recs] != [g.instance for g in greedy]:
        raise ValueError("the rule's and greedy play's records are of different instances")
    if not recs:
        raise ValueError("no records to score")
    ratios = [r.makespan / g.makespan for r, g in zip(recs, greedy, strict=True)
              if r.makespan is not None and g.makespan]
    return RuleScore(rule=rule, success_rate=float(np.mean([r.success for r in recs])),
                     slowdown=float(np.mean(ratios)) if ratios else None,
                     paired_instances=len(ratios), deadlocks=sum(r.deadlock for r in recs))


def ranked(scores: Iterable[RuleScore],
           tolerance: float = SUCCESS_TOLERANCE) -> list[RuleScore]:
    """The rules within ``tolerance`` of the best success rate, fastest first, then the rest,
    most successful first (stable: grid order breaks ties)."""
    pool = list(scores)
    if not pool:
        raise ValueError("no rules to choose from")
    if not tolerance >= 0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance!r}")
    best = max(s.success_rate for s in pool)
    near = [s for s in pool if s.success_rate >= best - tolerance - 1e-12]
    rest = [s for s in pool if s.success_rate < best - tolerance - 1e-12]
    return (sorted(near, key=lambda s: np.inf if s.slowdown is None else s.slowdown)
            + sorted(rest, key=lambda s: -s.success_rate))


def choose(scores: Iterable[RuleScore], tolerance: float = SUCCESS_TOLERANCE) -> RuleScore:
    """The fastest rule among those within ``tolerance`` of the best success rate."""
    return ranked(scores, tolerance)[0]


def pool(per_policy: Sequence[Sequence[RuleScore]]) -> list[RuleScore]:
    """One score per rule scored for every policy: mean success rate and mean slowdown over
    the policies (each policy's set counts once, whatever its size), summed counts. The rule
    ``choose`` takes from these is the best single default for all of them."""
    if not per_policy:
        return []
    common = set.intersection(*({s.rule for s in scores} for scores in per_policy))
    out = []
    for rule in (s.rule for s in per_policy[0] if s.rule in common):
        mine = [next(s for s in scores if s.rule == rule) for scores in per_policy]
        slow = [s.slowdown for s in mine if s.slowdown is not None]
        out.append(RuleScore(rule=rule,
                             success_rate=float(np.mean([s.success_rate for s in mine])),
                             slowdown=float(np.mean(slow)) if len(slow) == len(mine) else None,
                             paired_instances=sum(s.paired_instances for s in mine),
                             deadlocks=sum(s.deadlocks for s in mine)))
    return out
