"""Replay of MCAP recordings (placeholder until recording lands)."""

from __future__ import annotations

import argparse


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="replay", description="Replay an sdhn MCAP recording.")
    parser.add_argument("recording", nargs="?", help="path of the .mcap file")
    parser.parse_args(argv)
    print("replay: not implemented yet")
    return 0
