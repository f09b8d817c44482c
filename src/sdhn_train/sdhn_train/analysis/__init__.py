"""Analysis of finished runs, kept out of the training core: ``figures`` (the paper's figures
and results table, from run logs and P_H snapshots) and ``experiments`` (the suite runner).
Nothing in the trainers imports this package."""
