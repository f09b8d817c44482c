"""How a measurement becomes a verdict on one of the paper's claims (the claims tables of
``protocol_report`` and ``budget_marks``): reproduced, contradicted, or inconclusive at this
budget, and no verdict at all on too few seeds."""

from __future__ import annotations

from sdhn_experiments.protocol_stats import Estimate

PAPER_BUDGET = "10-20M"  # team-steps per run in the paper's configs
PAPER_MAKESPAN_RATIO = 0.77  # "a 23 % reduction in makespan compared to MAPPO"
MIN_VERDICT_SEEDS = 3
"""Fewest runs per method a verdict rests on: with fewer, a bootstrap over seeds has (almost) no
spread to draw, and one seed against one would 'reproduce' or 'contradict' on a coin toss."""


def too_few(*seeds: int) -> str | None:
    """The verdict when a side has fewer than MIN_VERDICT_SEEDS runs, else None."""
    n = min(seeds)
    if n >= MIN_VERDICT_SEEDS:
        return None
    return f"inconclusive: {n} seed{'s' if n != 1 else ''} (a verdict needs {MIN_VERDICT_SEEDS})"


def verdict(est: Estimate, better_above: float) -> str:
    """'reproduced' when the interval lies above ``better_above``, 'contradicted' below it."""
    if est.low > better_above:
        return "reproduced"
    if est.high < better_above:
        return "contradicted"
    return "inconclusive at this budget"


def makespan_verdict(ratio: Estimate) -> str:
    """The makespan claim (SDHN's 23 % below MAPPO's) from SDHN / MAPPO with its interval."""
    if ratio.high <= PAPER_MAKESPAN_RATIO:
        return "reproduced"
    if ratio.low > PAPER_MAKESPAN_RATIO:
        return "contradicted"
    return "inconclusive at this budget"
