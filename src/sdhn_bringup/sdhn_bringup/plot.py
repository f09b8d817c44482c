"""Plot a launched run: per-episode makespan (NC when not completed) and success first, return
second under the reward the simulator named, from ``<run_dir>/episodes.csv`` (written by the
launcher), next to a training curve when given: the per-episode returns of a launcher run in
train mode (its ``episodes.csv``), or the ``metrics.csv`` of an in-process training run.

    python -m sdhn_bringup.plot RUN_DIR [--train-run TRAIN_RUN_DIR] [--out PNG]
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

from sdhn_sim.episode import EpisodeResult
from sdhn_train.metrics_file import metrics_path, read_series


def read_episodes(run_dir: Path) -> list[EpisodeResult]:
    path = run_dir / "episodes.csv"
    rows = csv.DictReader(path.read_text().splitlines()) if path.exists() else []
    return [EpisodeResult.from_csv_row(row) for row in rows]


def reward_name(run_dir: Path) -> str:
    """The reward the simulator paid (its ``started`` event), or ``?`` if it did not say."""
    path = run_dir / "status" / "sim-events.jsonl"
    for line in path.read_text().splitlines() if path.exists() else []:
        try:
            event = json.loads(line)
        except ValueError:
            continue
        if isinstance(event, dict) and event.get("event") == "started":
            return str(event.get("reward", "?"))
    return "?"


def read_train_curve(train_run: Path,
                     tag: str = "charts/episodic_return") -> list[tuple[int, float]]:
    """(team env-steps, episode return) points of a training run."""
    episodes = read_episodes(train_run)
    if episodes:
        steps = 0
        points = []
        for e in episodes:
            steps += e.length
            points.append((steps, e.episode_return))
        return points
    path = metrics_path(train_run)
    if not path.exists():
        return []
    series = read_series(path)
    if tag not in series:
        return []
    at, values = series[tag]
    return [(int(s), float(v)) for s, v in zip(at, values, strict=True)]


def plot_run(run_dir: Path, train_run: Path | None = None, out: Path | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    episodes = read_episodes(run_dir)
    curve = read_train_curve(train_run) if train_run is not None else []
    panels = 3 if curve else 2
    fig, axes = plt.subplots(1, panels, figsize=(4.2 * panels, 3.4))
    ks = [e.episode for e in episodes]
    lengths = [e.length for e in episodes]
    done = [e.completed for e in episodes]
    colors = ["tab:green" if d else "tab:gray" for d in done]
    axes[0].bar(ks, lengths, color=colors)
    for k, length, d in zip(ks, lengths, done, strict=True):
        if not d:
            axes[0].text(k, length, "NC", ha="center", va="bottom", fontsize=8)
    axes[0].set(title=f"deployed: makespan, success {sum(done)}/{len(done)} (grey = NC)",
                xlabel="episode", ylabel="steps")
    axes[1].bar(ks, [e.episode_return for e in episodes], color="tab:blue")
    axes[1].set(title=f"deployed: return ({reward_name(run_dir)} reward)", xlabel="episode",
                ylabel="team return")
    if curve:
        axes[2].plot([s for s, _ in curve], [v for _, v in curve], marker="o")
        reward = reward_name(train_run) if train_run is not None else "?"
        axes[2].set(title=f"training: episode return ({reward} reward)", xlabel="team env-steps",
                    ylabel="team return")
    fig.tight_layout()
    out = out or run_dir / "episodes.png"
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="launch_plot", description=__doc__)
    p.add_argument("run_dir", type=Path)
    p.add_argument("--train-run", type=Path)
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    print(plot_run(args.run_dir, args.train_run, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
