"""``sdhn_sim replay FILE [--summary] [--rate X] [--export-episode K [--out DIR] [--gif OUT.gif]
[--mp4 OUT.mp4] [--hypergraph]] [--add-viz [--out NEW.mcap]] [--foxglove [--host H] [--port P]
[--rate X] [--loop]]``.

--summary          per-episode table: the simulator's EpisodeSummary messages, recomputed from the
                   recorded TeamState for episodes without one (source column says which).
--rate X           republish every recorded message on its own topic at X times the recorded speed
                   (1 = as recorded, 0.001..1000), each topic with the QoS recorded for it (its
                   channel's offered_qos_profiles, adapted as ros2 bag play does:
                   recording.rosbag2.replay_profile), or, for a recording without it, the
                   contract's (policy/weights latched, hypergraph best effort, the rest STEP).
                   Waits up to --wait seconds for subscribers first. Flow control: every reliable
                   topic waits for its matched subscribers to acknowledge before its history window
                   could overwrite an unacknowledged sample, and once more before exiting; a slow
                   subscriber slows the replay instead of losing messages. Messages not
                   acknowledged within --ack-timeout are counted, named in one line, and the exit
                   code is 1.
--export-episode K episode K rendered from the recorded TeamState positions, on the MAIF map of
--out DIR          the recorded instance id (recording.reader): PNG frames (frame_<step>.png) into
--gif OUT.gif      DIR, and/or an animated GIF / an MP4 with goals outlined, trails (--trail N
--mp4 OUT.mp4      steps), a caption with the outcome and, with --hypergraph, the latest sampled
                   hypergraph (recording.animation); --fps F (default 8), --every K (every K-th
                   step and the last; default 1), --cell-px (default 16 for PNG, 10 for GIF/MP4).
                   K = completed: the last episode whose EpisodeSummary says completed (the last
                   finished one, said so, when none completed).
--add-viz          write a copy with the viz channels (/viz/scene, /viz/hypergraph,
--out NEW.mcap     /viz/hypergraph/p_h, /viz/metrics, /viz/episodes) derived from the recorded
                   team messages, for a recording made with viz:=false (default NEW:
                   <stem>-viz.mcap beside it, never overwritten; the input is never modified). A
                   recording that already has them is reported and left alone (exit 0).
--recover OUT.mcap rewrite what the recording holds (all of it, or up to the damage a killed
                   recorder leaves) as a complete rosbag2 MCAP file: summary, index, end magic,
                   the rosbag2 metadata record (recording.recover); never over an existing file.
--foxglove         serve the recording's viz channels (the live viz node's) on a Foxglove
                   WebSocket at ws://HOST:PORT (--host 127.0.0.1, --port 8765, 0 = any free port),
                   paced by the recorded log times at --rate X (default 1); playback starts when
                   a client subscribes, ends after the last state (--loop: starts over until
                   Ctrl-C or SIGTERM, which both end with one line and exit code 0). The viz
                   node's server (the Foxglove SDK's), each client logged. A port in use (--port)
                   or an address that is not this machine's (--host) is one line, exit code 2.

With no action flag it prints the topics and message counts. Exit codes: 0 done (also for a
truncated recording: the readable part is used and one line says where it stops), 1 the requested
episode is not in the recording or --rate could not deliver every message, 2 bad
arguments, a port in use, or not an MCAP file.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time
from collections import Counter
from pathlib import Path

from sdhn_sim.recording.reader import (
    NotMcapError,
    Recording,
    episode_frames,
    episode_rows,
    format_rows,
    fresh_path,
    read_recording,
    viz_topics,
    write_with_viz,
)

MIN_RATE, MAX_RATE = 0.001, 1000.0



def episode_spec(text: str) -> int | str:
    """An episode number, or ``completed`` (resolved against the recording by ``pick_episode``)."""
    if text == "completed":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}; allowed: an episode number or "
                                         "'completed'") from None


def pick_episode(rec: Recording, spec: int | str) -> int | None:
    """The episode ``--export-episode`` names; None (after one line) when there is none."""
    if isinstance(spec, int):
        return spec
    rows = episode_rows(rec)
    done = [r.episode for r, _ in rows if r.completed]
    if done:
        return done[-1]
    if rows:
        print(f"replay: no recorded episode completed; exporting the last finished one "
              f"(episode {rows[-1].result.episode})")
        return rows[-1].result.episode
    print(f"replay: error: {rec.path} has no finished episode to export", file=sys.stderr)
    return None


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="replay", description="Summarise, republish or render "
                                     "an sdhn MCAP recording.")
    parser.add_argument("recording", help="path of the .mcap file")
    parser.add_argument("--summary", action="store_true", help="print per-episode summaries")
    parser.add_argument("--rate", type=float, default=None, metavar="X",
                        help="republish at X times the recorded speed (X > 0)")
    parser.add_argument("--wait", type=float, default=2.0, metavar="S",
                        help="with --rate: seconds to wait for subscribers before publishing")
    parser.add_argument("--ack-timeout", type=float, default=10.0, metavar="S",
                        help="with --rate: seconds to wait for subscribers' acknowledgements")
    parser.add_argument("--export-episode", type=episode_spec, default=None, metavar="K",
                        help="render episode K (a number, or 'completed': the last episode "
                        "whose summary says completed, else the last one) with --out, --gif "
                        "or --mp4")
    parser.add_argument("--out", type=Path, default=None, metavar="PATH",
                        help="directory for --export-episode frames; file for --add-viz")
    parser.add_argument("--cell-px", type=int, default=None,
                        help="pixels per grid cell in frames (default 16 for PNG, 10 for GIF/MP4)")
    parser.add_argument("--gif", type=Path, default=None, metavar="OUT.gif",
                        help="with --export-episode: write an animated GIF of the episode")
    parser.add_argument("--mp4", type=Path, default=None, metavar="OUT.mp4",
                        help="with --export-episode: write an MP4 of the episode")
    parser.add_argument("--fps", type=float, default=8.0, help="GIF/MP4 frames per second")
    parser.add_argument("--every", type=int, default=1, metavar="K",
                        help="GIF/MP4: every K-th step (and always the last)")
    parser.add_argument("--trail", type=int, default=8, metavar="N",
                        help="GIF/MP4: steps of trail behind each robot (0 = none)")
    parser.add_argument("--hypergraph", action="store_true",
                        help="GIF/MP4: draw the latest recorded sampled hypergraph")
    parser.add_argument("--add-viz", action="store_true",
                        help="write a copy with the derived /viz/* channels (--out NEW.mcap)")
    parser.add_argument("--recover", type=Path, default=None, metavar="OUT.mcap",
                        help="rewrite what a damaged recording holds (a killed recorder's) as "
                        "a complete rosbag2 MCAP file that any MCAP reader opens")
    parser.add_argument("--foxglove", action="store_true",
                        help="serve the viz channels on a Foxglove WebSocket (--rate = speed)")
    parser.add_argument("--host", default="127.0.0.1", help="with --foxglove: address to bind")
    parser.add_argument("--port", type=int, default=8765,
                        help="with --foxglove: port (0 = any free port)")
    parser.add_argument("--debug", action="store_true",
                        help="show tracebacks of refused inputs and unwritable outputs")
    parser.add_argument("--loop", action="store_true",
                        help="with --foxglove: start over after the last state until Ctrl-C")
    args = parser.parse_args(argv)
    if args.rate is not None and not MIN_RATE <= args.rate <= MAX_RATE:
        parser.error(f"--rate: {args.rate}; allowed: {MIN_RATE}..{MAX_RATE:g} "
                     "(1 = recorded speed)")
    for name in ("wait", "ack_timeout"):
        if not 0 <= getattr(args, name) <= 3600:
            parser.error(f"--{name.replace('_', '-')}: {getattr(args, name)}; allowed: 0..3600")
    if args.export_episode is not None and args.add_viz:
        parser.error("--export-episode and --add-viz: one at a time (each takes --out)")
    animated = args.gif is not None or args.mp4 is not None
    if args.export_episode is not None and args.out is None and not animated:
        parser.error("--export-episode K needs --out DIR, --gif OUT.gif or --mp4 OUT.mp4")
    if (animated or args.hypergraph) and args.export_episode is None:
        parser.error("--gif, --mp4 and --hypergraph go with --export-episode K")
    for flag, path, suffix in (("--gif", args.gif, ".gif"), ("--mp4", args.mp4, ".mp4")):
        if path is not None and path.suffix.lower() != suffix:
            parser.error(f"{flag}: {path}; allowed: a path ending in {suffix}")
    if not 0.5 <= args.fps <= 60:
        parser.error(f"--fps: {args.fps}; allowed: 0.5..60")
    if args.every < 1:
        parser.error(f"--every: {args.every}; allowed: >= 1")
    if args.trail < 0:
        parser.error(f"--trail: {args.trail}; allowed: >= 0")
    if args.out is not None and args.export_episode is None and not args.add_viz:
        parser.error("--out goes with --export-episode K or --add-viz")
    if args.add_viz and args.out is not None and args.out.suffix != ".mcap":
        parser.error(f"--out: {args.out}; allowed with --add-viz: a path ending in .mcap")
    if args.recover is not None and args.recover.suffix != ".mcap":
        parser.error(f"--recover: {args.recover}; allowed: a path ending in .mcap")
    if not 0 <= args.port <= 65535:
        parser.error(f"--port: {args.port}; allowed: 0..65535 (0 = any free port)")
    if (args.host != "127.0.0.1" or args.port != 8765 or args.loop) and not args.foxglove:
        parser.error("--host, --port and --loop go with --foxglove")
    if args.cell_px is not None and args.cell_px < 3:
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
        if args.debug:
            raise
        print(f"replay: error: {e}", file=sys.stderr)
        return 2
    if rec.truncated is not None:
        print(f"replay: {rec.truncated.line()}", file=sys.stderr)
    code = 0
    if args.summary:
        print(format_rows(episode_rows(rec)))
    if args.export_episode is not None:
        args.export_episode = pick_episode(rec, args.export_episode)
        if args.export_episode is None:
            return 1
    try:
        if args.export_episode is not None and args.out is not None:
            code = export(rec, args.export_episode, args.out, args.cell_px or 16)
        if args.export_episode is not None and code == 0 and (args.gif or args.mp4):
            code = export_animation(rec, args)
        if args.add_viz:
            code = max(code, add_viz(rec, args.out))
    except OSError as e:  # a full disk, a read-only or missing directory
        if args.debug:
            raise
        print(f"replay: error: --out: cannot write {e.filename or args.out}: "
              f"{e.strerror or e}", file=sys.stderr)
        return 2
    if args.recover is not None:
        code = max(code, recover_file(rec, args.recover, args.debug))
    if args.foxglove:
        code = max(code, serve_foxglove(rec, args.host, args.port, args.rate or 1.0, args.loop))
    elif args.rate is not None:
        code = max(code, republish(rec, args.rate, args.wait, args.ack_timeout))
    if not (args.summary or args.export_episode is not None or args.rate is not None
            or args.add_viz or args.foxglove or args.recover is not None):
        for topic, count in sorted(rec.topics().items()):
            print(f"{count:>8}  {topic}")
    if rec.undecodable:
        where = ", ".join(f"{t}={n}" for t, n in sorted(rec.undecodable.items()))
        print(f"replay: skipped {sum(rec.undecodable.values())} messages of an unknown type or "
              f"with malformed CDR ({where})", file=sys.stderr)
    return code


def export(rec: Recording, episode: int, out: Path, cell_px: int) -> int:
    from PIL import Image

    try:
        frames = episode_frames(rec, episode, cell_px)
    except KeyError:
        print(f"replay: error: episode {episode} has no recorded state", file=sys.stderr)
        return 1
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        print(f"replay: error: --out: {out} exists and is not an empty directory; frames are "
              "never written over other files", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    for step, image in zip(frames.steps, frames.images, strict=True):
        Image.fromarray(image).save(out / f"frame_{step:05d}.png")
    print(f"wrote {len(frames.images)} frames of episode {episode} to {out} ({frames.map_note})")
    return 0


def export_animation(rec: Recording, args: argparse.Namespace) -> int:
    """``--gif`` / ``--mp4`` of ``--export-episode`` (recording.animation)."""
    from sdhn_sim.recording.animation import (
        NoHypergraphError,
        episode_animation,
        write_gif,
        write_mp4,
    )

    targets = [(flag, path, write) for flag, path, write in (
        ("--gif", args.gif, write_gif), ("--mp4", args.mp4, write_mp4)) if path is not None]
    for flag, path, _ in targets:  # before rendering: the error names its own flag, not --out
        problem = ("is a directory" if path.is_dir() else
                   "is not in an existing directory" if not path.parent.is_dir() else None)
        if problem:
            print(f"replay: error: {flag}: {path} {problem}; allowed: a file path in an existing "
                  "directory", file=sys.stderr)
            return 2
    try:
        anim = episode_animation(rec, args.export_episode, cell_px=args.cell_px or 10,
                                 trail=args.trail, hypergraph=args.hypergraph, every=args.every)
    except KeyError:
        print(f"replay: error: episode {args.export_episode} has no recorded state",
              file=sys.stderr)
        return 1
    except NoHypergraphError as e:
        print(f"replay: error: --hypergraph: {e}", file=sys.stderr)
        return 1
    h, w = anim.frames[0].shape[:2]
    graphs = f", hypergraph on {anim.hypergraph_frames}" if args.hypergraph else ""
    for flag, path, write in targets:
        try:
            write(anim, path, args.fps)
        except OSError as e:  # a full disk, no permission
            print(f"replay: error: {flag}: cannot write {path}: {e.strerror or e}",
                  file=sys.stderr)
            return 2
        print(f"wrote {path}: episode {anim.episode}, {len(anim.frames)} frames "
              f"({w}x{h}, {args.fps:g} fps{graphs}), {anim.outcome}; {anim.map_note}")
    return 0


def recover_file(rec: Recording, out: Path, debug: bool = False) -> int:
    """``--recover``: the readable part of ``rec`` as a complete rosbag2 MCAP (recording.recover).
    """
    from sdhn_sim.recording.recover import recover

    if not out.parent.is_dir():
        print(f"replay: error: --recover: {out.parent} is not a directory; allowed: a new .mcap "
              "file in an existing directory", file=sys.stderr)
        return 2
    if out.resolve() == rec.path.resolve():
        print("replay: error: --recover: the input itself; allowed: a new file",
              file=sys.stderr)
        return 2
    try:
        done = recover(rec, out)
    except OSError as e:
        if debug:
            raise
        print(f"replay: error: --recover: cannot write {out}: {e.strerror or e}",
              file=sys.stderr)
        return 2
    state = "damaged" if rec.truncated is not None else "complete"
    note = "" if done.path == out else f" ({out} exists)"
    print(f"wrote {done.path}{note}: {done.messages} messages of {done.topics} ROS topics from "
          f"the {state} {rec.path.name}, with summary, index and rosbag2 metadata")
    return 0


def add_viz(rec: Recording, out: Path | None) -> int:
    """Write a copy of ``rec`` with the derived viz channels (see ``write_with_viz``)."""
    have = viz_topics(rec)
    if have:
        counts = ", ".join(f"{t}={c}" for t, c in sorted(have.items()))
        print(f"replay: {rec.path} already has viz channels ({counts}); nothing written")
        return 0
    requested = out or rec.path.with_name(f"{rec.path.stem}-viz.mcap")
    if not requested.parent.is_dir():  # never create directories the user did not ask for
        print(f"replay: error: --out: {requested.parent} is not a directory; allowed: a new "
              ".mcap file in an existing directory", file=sys.stderr)
        return 2
    target = fresh_path(requested)  # never the input, never an existing file
    # Atomic: written beside the target, renamed when complete; a failed write (a full disk)
    # leaves nothing (sdhn_base.litter cleans a killed writer's temporary file).
    tmp = target.with_name(f".{target.name}.{os.getpid()}.w.tmp")
    try:
        done = write_with_viz(rec, tmp)
        if done.team_ns is not None:
            os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
    if done.team_ns is None:
        print(f"replay: {rec.path} has no sdhn_msgs/TeamState to draw; nothing written")
        return 0
    written = ", ".join(f"{t}={c}" for t, c in sorted(done.written.items())) or "none"
    dropped = ", ".join(f"{k}={v}" for k, v in sorted(done.dropped.items())) or "none"
    note = "" if target == requested else f" ({requested} exists)"
    print(f"wrote {target}{note}: {done.copied} recorded messages + viz of {done.team_ns}: "
          f"{written}; dropped: {dropped}")
    return 0


def serve_foxglove(rec: Recording, host: str, port: int, rate: float, loop: bool) -> int:
    """Serve the viz channels derived from ``rec`` on a Foxglove WebSocket, paced by log time.
    The live viz node's server (the Foxglove SDK's, ``sdhn_sim.viz.server``), each client
    logged. SIGTERM stops it as Ctrl-C does: one line, exit 0. Every line goes through one lock
    (``say``): the server's threads log too, and lines never interleave."""
    from sdhn_sim.recording.reader import decode, team_kind, team_namespace
    from sdhn_sim.viz.channels import VizDeriver
    from sdhn_sim.viz.server import BindError, VizServer, ws_url

    ns = team_namespace(rec)
    if ns is None:
        print(f"replay: error: {rec.path} has no sdhn_msgs/TeamState to draw", file=sys.stderr)
        return 2
    team = [(m, kind) for m in rec.messages
            if (kind := team_kind(m.topic, m.type_name, m.encoding, ns)) is not None]
    team.sort(key=lambda mk: mk[0].log_time_ns)
    try:
        server = VizServer(host, port, f"sdhn replay {rec.path.name}",
                           lambda line: say(f"replay: {line}"))
    except BindError as error:
        print(f"replay: error: --{error.field}: {error.message}", file=sys.stderr)
        return 2
    span = (team[-1][0].log_time_ns - team[0][0].log_time_ns) / 1e9 if team else 0.0
    states = sum(1 for _, k in team if k == "state")
    sent = passes = 0
    last_line = time.monotonic()
    # The handler before the serving line: whoever reads that line may send SIGTERM at once
    # (the default action would kill the process without its closing line).
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        say(f"replay: serving {rec.path} on {ws_url(host, server.port)} ({states} states, "
            f"{span:.1f} s recorded, rate {rate}x); playback starts when a client subscribes, "
            "Ctrl-C stops")
        while not server.new_subscriber.wait(0.1):
            pass
        while True:
            deriver = VizDeriver()
            start = time.monotonic()
            t0 = team[0][0].log_time_ns if team else 0
            for m, kind in team:
                delay = (m.log_time_ns - t0) / 1e9 / rate - (time.monotonic() - start)
                if delay > 0:
                    time.sleep(delay)
                try:
                    out = deriver.derive(kind, decode(m), m.log_time_ns)
                except Exception:  # malformed CDR in the file: skip that message
                    continue
                for v in out:
                    server.log(v.topic, v.data, v.log_time_ns)
                    sent += 1
            passes += 1
            if not loop:
                say(f"replay: served {sent} viz messages ({states} states) in "
                    f"{time.monotonic() - start:.2f} s")
                time.sleep(0.5)  # let the server hand the last messages over
                break
            # A short file loops fast: a pass takes at least LOOP_MIN_PASS_S, and the progress
            # line comes at most every LOOP_LINE_PERIOD_S (it came every 40 ms).
            time.sleep(max(0.0, LOOP_MIN_PASS_S - (time.monotonic() - start)))
            if time.monotonic() - last_line >= LOOP_LINE_PERIOD_S:
                last_line = time.monotonic()
                say(f"replay: served {sent} viz messages in {passes} passes")
    except KeyboardInterrupt:
        say(f"replay: stopped after {sent} viz messages ({passes} complete passes)")
    finally:
        signal.signal(signal.SIGTERM, previous)
        server.close()
    return 0


LOOP_MIN_PASS_S = 1.0
"""Shortest pass of ``--loop`` (a file of one state would otherwise loop without pause)."""
LOOP_LINE_PERIOD_S = 30.0
"""``--loop`` prints its progress line at most this often."""
_SAY = threading.Lock()


def say(line: str) -> None:
    """Print one whole line (the server's threads print too: one lock, one write)."""
    with _SAY:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()


def _warn(line: str) -> None:
    print(f"replay: warning: {line}", file=sys.stderr)


def _interrupt(signum: int, frame: object) -> None:
    """SIGTERM (a service manager, ``kill``): stop as Ctrl-C does, with the closing line."""
    raise KeyboardInterrupt


def republish(rec: Recording, rate: float, wait: float, ack_timeout: float = 10.0) -> int:
    """Publish the raw CDR of every message again, paced by the recorded log times / rate
    (viz channels, which are not ROS messages, are left out), with flow control on reliable
    topics (module doc). 0 when every reliable message was acknowledged, else 1."""
    import rclpy
    from rclpy.context import Context
    from rclpy.duration import Duration
    from rclpy.qos import ReliabilityPolicy

    from sdhn_base.ros import topics
    from sdhn_base.ros.qos import LATCHED, SENSOR, STEP
    from sdhn_sim.data_files import fastdds_replay_profile
    from sdhn_sim.recording.reader import current_cdr
    from sdhn_sim.recording.rosbag2 import recorded_profile
    from sdhn_sim.recording.schema import message_class

    os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(fastdds_replay_profile()))
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node("replay", context=context)
    pubs = {}
    reliable: set[str] = set()
    window: dict[str, int] = {}
    messages = [m for m in rec.messages if m.encoding == "cdr"]
    skipped: Counter[str] = Counter()
    try:
        for m in messages:
            if m.topic not in pubs and m.topic not in skipped:
                profile = recorded_profile(rec.channels.get(m.channel_id), _warn) or (
                    LATCHED if topics.team_of(m.topic, topics.WEIGHTS) else
                    SENSOR if topics.team_of(m.topic, topics.HYPERGRAPH) else STEP)
                try:
                    cls = message_class(m.type_name)
                except (ValueError, LookupError, ImportError):  # schema.UnknownMessageType
                    skipped[m.topic] += 1
                    continue
                pubs[m.topic] = node.create_publisher(cls, m.topic, profile)
                if profile.reliability == ReliabilityPolicy.RELIABLE:
                    reliable.add(m.topic)
                    # samples in flight before waiting: below the history depth, so an
                    # unacknowledged sample is never overwritten (1 for the latched weights)
                    window[m.topic] = max(1, profile.depth * 3 // 4)
            elif m.topic in skipped:
                skipped[m.topic] += 1
        for topic, n in sorted(skipped.items()):
            print(f"replay: skipped {n} messages of {topic}: unknown type", file=sys.stderr)
        messages = [m for m in messages if m.topic in pubs]
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline and any(p.get_subscription_count() == 0
                                                  for p in pubs.values()):
            time.sleep(0.05)
        ordered = sorted(messages, key=lambda m: m.log_time_ns)
        if not ordered:
            return 0
        timeout, stalled = Duration(seconds=ack_timeout), Duration(seconds=0.1)
        in_flight: Counter[str] = Counter()  # published since the last full acknowledgement
        lost: Counter[str] = Counter()  # not acknowledged within the timeout
        t0, start = ordered[0].log_time_ns, time.monotonic()
        for m in ordered:
            delay = (m.log_time_ns - t0) / 1e9 / rate - (time.monotonic() - start)
            if delay > 0:
                time.sleep(delay)
            pub = pubs[m.topic]
            if m.topic in reliable and in_flight[m.topic] >= window[m.topic]:
                # A topic that already timed out is not waited on for long again: its
                # subscriber is stalled, and the replay keeps its pace for the others.
                if not pub.wait_for_all_acked(stalled if m.topic in lost else timeout):
                    lost[m.topic] += in_flight[m.topic]
                in_flight[m.topic] = 0
            pub.publish(current_cdr(m))
            in_flight[m.topic] += 1
        for topic in reliable:  # the last window, before the writers go away
            if in_flight[topic] and not pubs[topic].wait_for_all_acked(timeout):
                lost[topic] += in_flight[topic]
        elapsed = time.monotonic() - start
        print(f"republished {len(ordered)} messages on {len(pubs)} topics in "
              f"{elapsed:.2f} s (rate {rate}x)")
        if lost:
            names = ", ".join(f"{t}={n}" for t, n in sorted(lost.items()))
            print(f"replay: error: {sum(lost.values())} messages not acknowledged within "
                  f"{ack_timeout:g} s by a matched subscriber ({names})", file=sys.stderr)
            return 1
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
