"""Experiments, kept out of the training core: suites and their runner (local or Ray), held-out
evaluation, the protocol's statistics and reports, the paper's figures, and carried runs.
Nothing in the trainers imports this package."""
