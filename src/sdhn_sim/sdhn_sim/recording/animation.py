"""Episodes you can watch: one recorded episode as an animated GIF or an MP4.

Each frame is the grid the PNG export draws (``sdhn_sim.envs.render.render_grid``: the map of the
recorded instance, goals as light squares, robots as filled squares, in the colours the viz node
gives them), with on top: each goal outlined in its robot's colour, each robot's trail over the
last ``trail`` steps, optionally the team's latest sampled hypergraph (a star per hyperedge from
its P_H-weighted centre to the robots in it, in the hyperedge's colour), and a caption line
(environment, episode, step, outcome) with a progress bar, which also keeps every frame distinct
(a GIF writer merges identical frames).

The GIF is palette-quantised and the frames can be thinned (``every``: every k-th step and always
the last) so a 100-step maif-10 episode stays a few hundred kB. The MP4 goes through
``imageio-ffmpeg``, whose wheel carries the ffmpeg binary (nothing is downloaded at run time).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from sdhn_base.ros import topics
from sdhn_sim.envs.render import render_grid, robot_colors
from sdhn_sim.episode import EpisodeResult
from sdhn_sim.recording.reader import (
    Recording,
    dropped_note,
    episode_map,
    episode_states,
    on_map,
    summaries_from_messages,
)

CAPTION_PX = 14  # height of the caption strip (the default bitmap font is 11 px high)
BAR_PX = 2  # progress bar under the caption
TEXT_RGB = (30, 30, 30)
BAR_RGB = (70, 130, 200)


class NoHypergraphError(LookupError):
    """--hypergraph was asked for a recording without hypergraph messages."""


@dataclass
class Animation:
    episode: int
    steps: list[int]  # the recorded step of each frame
    frames: list[npt.NDArray[np.uint8]]  # RGB [H, W, 3]
    map_note: str
    outcome: str  # "completed, makespan 37" / "not completed (NC) after 500 steps" / "unknown"
    hypergraph_frames: int  # frames with a hypergraph drawn


def _centres(positions: npt.NDArray[np.int64], cell_px: int) -> npt.NDArray[np.float64]:
    """[..., 2] pixel centres (x, y) of grid cells (x, y)."""
    return positions.astype(np.float64) * cell_px + cell_px / 2.0


def _hypergraphs(rec: Recording) -> list[tuple[int, npt.NDArray[np.float32],
                                               npt.NDArray[np.bool_]]]:
    """(log time, P_H [N, M], members [N, M]) of every recorded Hypergraph, by log time."""
    out = []
    for raw, m in rec.decoded(f"/{topics.HYPERGRAPH}", "sdhn_msgs/msg/Hypergraph"):
        n, k = int(m.num_robots), int(m.num_hyperedges)
        p_h = np.frombuffer(np.asarray(m.p_h, np.float32).tobytes(), np.float32)
        if n < 1 or k < 1 or p_h.size != n * k or not np.isfinite(p_h).all():
            continue  # malformed: nothing to draw
        inc = np.frombuffer(bytes(m.incidence), np.uint8)
        members = (inc.reshape(n, k) > 0) if inc.size == n * k else (p_h.reshape(n, k) >= 0.5)
        out.append((raw.log_time_ns, p_h.reshape(n, k), members))
    out.sort(key=lambda g: g[0])
    return out


def episode_animation(rec: Recording, episode: int, *, cell_px: int = 10, trail: int = 8,
                      hypergraph: bool = False, every: int = 1) -> Animation:
    """The frames of ``episode`` (KeyError if no state of it was recorded; NoHypergraphError if
    ``hypergraph`` and the recording has none)."""
    from PIL import Image, ImageDraw

    st = episode_states(rec, episode)
    obstacles, goals, note = episode_map(st.env_name, st.instance_id, st.positions)
    st = on_map(st, obstacles)
    note += dropped_note(st)
    graphs = _hypergraphs(rec) if hypergraph else []
    if hypergraph and not graphs:
        raise NoHypergraphError(f"{rec.path} has no hypergraph messages (the trainer publishes "
                                "them in train mode)")
    summary = summaries_from_messages(rec).get(episode)
    outcome = ("unknown" if summary is None else
               f"completed, makespan {summary.makespan}" if summary.completed else
               f"not completed (NC) after {summary.length} steps")
    n = st.positions.shape[1]
    colors = [tuple(int(v) for v in c) for c in robot_colors(n)]
    keep = [i for i in range(len(st.steps)) if i % every == 0 or i == len(st.steps) - 1]
    frames, drawn = [], 0
    last = st.steps[-1]
    top = CAPTION_PX + BAR_PX

    def box(x: int, y: int, inset: int) -> tuple[int, int, int, int]:
        return (x * cell_px + inset, top + y * cell_px + inset,
                (x + 1) * cell_px - inset, top + (y + 1) * cell_px - inset)

    for i in keep:
        pos = st.positions[i]
        grid = render_grid(obstacles, pos, goals, cell_px)
        h, w = grid.shape[:2]
        canvas = Image.new("RGB", (w, h + top), (255, 255, 255))
        canvas.paste(Image.fromarray(grid), (0, top))
        draw = ImageDraw.Draw(canvas)
        if goals is not None:
            for r, (gx, gy) in enumerate(np.asarray(goals).reshape(-1, 2).tolist()):
                draw.rectangle(box(gx, gy, 1), outline=colors[r], width=max(1, cell_px // 8))
        tail = st.positions[max(0, i - trail):i + 1]  # [t, N, 2]
        width = max(1, cell_px // 4)
        for r in range(n):
            pts = _centres(tail[:, r], cell_px)
            light = tuple((c + 255) // 2 for c in colors[r])
            if len(pts) > 1:
                draw.line([(float(x), float(y) + top) for x, y in pts], fill=light, width=width)
        if graphs:
            drawn += _draw_hypergraph(draw, graphs, st.log_times[i], pos, cell_px=cell_px,
                                      top=top)
        for r, (x, y) in enumerate(pos.tolist()):  # robots over trails and hyperedges
            draw.rectangle(box(x, y, max(2, cell_px // 6)), fill=colors[r], outline=TEXT_RGB)
        step = st.steps[i]
        caption = _caption(draw, w - 4, st.env_name, episode, step=step, last=last,
                           summary=summary if step == last else None)
        draw.text((3, 1), caption, fill=TEXT_RGB)
        draw.rectangle((0, CAPTION_PX, round(w * step / max(last, 1)), top - 1), fill=BAR_RGB)
        frames.append(np.asarray(canvas))
    return Animation(episode, [st.steps[i] for i in keep], frames, note, outcome, drawn)


def _caption(draw: object, width: int, env_name: str, episode: int, *, step: int, last: int,
             summary: EpisodeResult | None) -> str:
    """The longest caption that fits ``width`` pixels (a maif-tiny frame is 120 px wide)."""
    from PIL import ImageDraw

    assert isinstance(draw, ImageDraw.ImageDraw)
    if summary is None:
        long_end = short_end = ""
    elif summary.completed:
        long_end = f" · completed, makespan {summary.makespan}"
        short_end = f" ms {summary.makespan}"
    else:
        long_end, short_end = " · not completed (NC)", " NC"
    for text in (f"{env_name} · episode {episode} · step {step}/{last}{long_end}",
                 f"episode {episode} · step {step}/{last}{long_end}",
                 f"ep {episode} · {step}/{last}{short_end}"):
        if draw.textlength(text) <= width:
            return text
    return f"{step}/{last}{short_end}"


def _draw_hypergraph(draw: object, graphs: list[tuple[int, npt.NDArray[np.float32],
                                                      npt.NDArray[np.bool_]]],
                     log_time_ns: int, pos: npt.NDArray[np.int64], *, cell_px: int,
                     top: int) -> int:
    """Draw the latest hypergraph recorded up to ``log_time_ns``; 1 if one was drawn."""
    from PIL import ImageDraw

    assert isinstance(draw, ImageDraw.ImageDraw)
    times = [g[0] for g in graphs]
    k = int(np.searchsorted(times, log_time_ns, side="right")) - 1
    if k < 0 or graphs[k][1].shape[0] != pos.shape[0]:
        return 0
    _, p_h, members = graphs[k]
    centres = _centres(pos, cell_px)
    edge_colors = [tuple(int(v) for v in c) for c in robot_colors(p_h.shape[1])]
    for j in range(p_h.shape[1]):
        idx = np.flatnonzero(members[:, j])
        if idx.size == 0:
            continue
        p = p_h[:, j].astype(np.float64)
        hub = (p[:, None] * centres).sum(0) / p.sum() if p.sum() > 1e-9 else centres.mean(0)
        for r in idx.tolist():
            draw.line([(float(hub[0]), float(hub[1]) + top),
                       (float(centres[r, 0]), float(centres[r, 1]) + top)],
                      fill=edge_colors[j], width=max(1, cell_px // 6))
    return 1


def write_gif(anim: Animation, path: Path, fps: float) -> None:
    """Palette GIF, looping, ``fps`` frames per second; the last frame held for a second."""
    import imageio.v3 as iio

    frame_ms = 1000.0 / fps
    durations = [frame_ms] * len(anim.frames)
    durations[-1] = max(frame_ms, 1000.0)
    _atomic(path, lambda tmp: iio.imwrite(tmp, np.stack(anim.frames), extension=".gif",
                                          duration=durations, loop=0, palettesize=64))


def write_mp4(anim: Animation, path: Path, fps: float) -> None:
    """H.264 MP4 (yuv420p, so every player opens it): the frames padded to even sizes."""
    import imageio.v3 as iio

    frames = np.stack(anim.frames)
    _, h, w, _ = frames.shape
    frames = np.pad(frames, ((0, 0), (0, h % 2), (0, w % 2), (0, 0)), constant_values=255)
    _atomic(path, lambda tmp: iio.imwrite(tmp, frames, extension=".mp4", plugin="FFMPEG",
                                          fps=fps, codec="libx264", macro_block_size=1,
                                          output_params=["-pix_fmt", "yuv420p", "-f", "mp4"]))


def _atomic(path: Path, write: object) -> None:
    """Write through a temporary file beside ``path`` and rename: never a half-written file."""
    import os

    assert callable(write)
    # .<name>.<pid>.w.tmp: the pattern sdhn_base.litter removes when a killed writer left it
    tmp = path.with_name(f".{path.name}.{os.getpid()}.w.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
