"""``sdhn_sim replay FILE [--summary] [--rate X] [--export-episode K --out DIR]``.

--summary          per-episode table: the simulator's EpisodeSummary messages, recomputed from the
                   recorded TeamState for episodes without one (source column says which).
--rate X           republish every recorded message on its own topic at X times the recorded speed
                   (1 = as recorded), with the contract's QoS (policy/weights latched, hypergraph
                   best effort, the rest STEP). Waits up to --wait seconds for subscribers first.
--export-episode K PNG frames (frame_<step>.png) of episode K rendered from the recorded TeamState
--out DIR          positions, on the MAIF map matched from the start cells (sdhn_sim.recording).

With no action flag it prints the topics and message counts. Exit codes: 0 done (also for a
truncated recording: the readable part is used and one line says where it stops), 1 the requested
episode is not in the recording, 2 bad arguments or not an MCAP file.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from sdhn_sim.recording import (
    NotMcapError,
    Recording,
    episode_frames,
    episode_rows,
    format_rows,
    read_recording,
)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="replay", description="Summarise, republish or render "
                                     "an sdhn MCAP recording.")
    parser.add_argument("recording", help="path of the .mcap file")
    parser.add_argument("--summary", action="store_true", help="print per-episode summaries")
    parser.add_argument("--rate", type=float, default=None, metavar="X",
                        help="republish at X times the recorded speed (X > 0)")
    parser.add_argument("--wait", type=float, default=2.0, metavar="S",
                        help="with --rate: seconds to wait for subscribers before publishing")
    parser.add_argument("--export-episode", type=int, default=None, metavar="K",
                        help="write PNG frames of episode K (needs --out)")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help="directory for --export-episode frames")
    parser.add_argument("--cell-px", type=int, default=16, help="pixels per grid cell in frames")
    args = parser.parse_args(argv)
    if args.rate is not None and not args.rate > 0:
        parser.error(f"--rate: {args.rate}; allowed: a number > 0 (1 = recorded speed)")
    if (args.export_episode is None) != (args.out is None):
        parser.error("--export-episode K and --out DIR go together")
    if args.cell_px < 3:
        parser.error(f"--cell-px: {args.cell_px}; allowed: >= 3")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        rec = read_recording(args.recording)
    except FileNotFoundError:
        print(f"replay: error: no such file {args.recording}", file=sys.stderr)
        return 2
    except (NotMcapError, OSError) as e:
        print(f"replay: error: {e}", file=sys.stderr)
        return 2
    if rec.truncated is not None:
        print(f"replay: {rec.truncated.line()}", file=sys.stderr)
    code = 0
    if args.summary:
        print(format_rows(episode_rows(rec)))
    if args.export_episode is not None:
        code = export(rec, args.export_episode, args.out, args.cell_px)
    if args.rate is not None:
        republish(rec, args.rate, args.wait)
    if not (args.summary or args.export_episode is not None or args.rate is not None):
        for topic, count in sorted(rec.topics().items()):
            print(f"{count:>8}  {topic}")
    return code


def export(rec: Recording, episode: int, out: Path, cell_px: int) -> int:
    from PIL import Image

    try:
        frames = episode_frames(rec, episode, cell_px)
    except KeyError:
        print(f"replay: error: episode {episode} has no recorded state", file=sys.stderr)
        return 1
    out.mkdir(parents=True, exist_ok=True)
    for step, image in zip(frames.steps, frames.images, strict=True):
        Image.fromarray(image).save(out / f"frame_{step:05d}.png")
    print(f"wrote {len(frames.images)} frames of episode {episode} to {out} ({frames.map_note})")
    return 0


def republish(rec: Recording, rate: float, wait: float) -> None:
    """Publish the raw CDR of every message again, paced by the recorded log times / rate."""
    import rclpy
    from rclpy.context import Context

    from sdhn_sim.qos import LATCHED, SENSOR, STEP
    from sdhn_sim.recording import message_class

    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node("replay", context=context)
    pubs = {}
    try:
        for m in rec.messages:
            if m.topic not in pubs:
                profile = (LATCHED if m.topic.endswith("/policy/weights") else
                           SENSOR if m.topic.endswith("/hypergraph") else STEP)
                pubs[m.topic] = node.create_publisher(message_class(m.type_name), m.topic, profile)
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline and any(p.get_subscription_count() == 0
                                                  for p in pubs.values()):
            time.sleep(0.05)
        ordered = sorted(rec.messages, key=lambda m: m.log_time_ns)
        if not ordered:
            return
        t0, start = ordered[0].log_time_ns, time.monotonic()
        for m in ordered:
            delay = (m.log_time_ns - t0) / 1e9 / rate - (time.monotonic() - start)
            if delay > 0:
                time.sleep(delay)
            pubs[m.topic].publish(m.data)
        print(f"republished {len(ordered)} messages on {len(pubs)} topics in "
              f"{time.monotonic() - start:.2f} s (rate {rate}x)")
        time.sleep(0.2)  # let reliable writers hand the last samples over
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
