"""In-process trainer command line (placeholder until the algorithm core lands)."""

from __future__ import annotations

import argparse


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="train", description="Train SDHN in one process.")
    parser.parse_args(argv)
    print("train: the in-process trainer is not implemented yet")
    return 0
