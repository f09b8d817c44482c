"""Compare deployment modes of one policy (greedy, sampled at temperatures, unstick) from
``evaluate_policy.py --out`` files: success with its interval, deadlocks, and the makespan over
the planner's on only the instances every mode completed (a fair makespan comparison: a mode
that solves harder instances is not charged for them).

    .venv/bin/python scripts/compare_eval_modes.py greedy.json t05.json t1.json [--markdown OUT]

Files holding several policies or sets are split by (policy, task, set); one table each.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

from sdhn_experiments.heldout_eval import modes_table, paired_makespan_ratios, print_table


def tables(results: list[dict[str, Any]]) -> str:
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in results:
        groups[(r["policy"], r["task"], r["set"])].append(r)
    out = []
    for (policy, task, which), runs in groups.items():
        n, paired = paired_makespan_ratios(runs)
        out += [f"{policy} on {task} / {which} ({runs[0]['summary']['instances']} instances; "
                f"paired makespan over the {n} every mode completed)", ""]
        out += modes_table([(r["mode"], r["summary"], pm)
                            for r, pm in zip(runs, paired, strict=True)])
        out.append("")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("files", nargs="+", type=Path, help="evaluate_policy.py --out JSON files")
    p.add_argument("--markdown", type=Path, help="write the tables here too")
    args = p.parse_args(argv)
    results: list[dict[str, Any]] = []
    try:
        for f in args.files:
            data = json.loads(f.read_text())
            if not isinstance(data, list):
                raise ValueError(f"{f}: not an evaluate_policy.py --out file (a JSON list)")
            results += data
        text = tables(results)
    except (OSError, ValueError, KeyError, TypeError) as e:
        print(f"compare_eval_modes: {e}", file=sys.stderr)
        return 2
    print_table(text, args.markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
