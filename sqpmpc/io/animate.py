"""``sqpmpc animate RUN_DIR``: an animation of a run from what the run wrote.

Reads the run folder's ``trajectory.npz`` (``t``, ``states``, ``ids``,
``references``, and, written by this version, ``diameters``, ``horizons`` and
the obstacles) and draws one frame per ``--step`` samples: every robot's
footprint (a circle of its diameter, in the colours of the plots), its
heading (a line from the centre to the rim), the path it has driven, its
predicted horizon (the plan computed at that sample, dots on a line), its
reference path (dashed) and the reference point now (x), the obstacles
(grey), and the time and the smallest clearance so far in the title; a legend
row under the plot says what each mark is. The frame takes the aspect of the
run's extent (:func:`frame_size`), so the arena fills it.

A ``.gif`` is written with Pillow (always available); a ``.mp4`` with
``imageio-ffmpeg`` when it is installed (``pip install imageio-ffmpeg``, it
ships its own ffmpeg). ``--frame K`` writes the frame of sample ``K`` alone as a
PNG. ``--scenario`` supplies the diameters and obstacles of
a run folder written before they were stored.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.io.files import load_trajectory
from sqpmpc.io.recording import robot_rgba

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["MAX_FRAMES", "RunData", "animate", "frame_count", "frame_size", "load_run",
           "render_frames", "write_frame"]

log = logging.getLogger(__name__)

MAX_FRAMES = 300
"""Default ``--step`` keeps the animation at most this many frames."""


class RunData:
    """What a run folder holds for drawing it.

    Attributes
    ----------
    name
        Scenario and scheme (from ``metrics.json`` when present).
    t, states, ids, references, diameters
        From ``trajectory.npz`` (``diameters`` from the scenario if given).
    horizons
        ``(k, n, N+1, 3)`` plans or ``None``.
    obstacle_positions, obstacle_diameters
        ``(k+1, O, 2)`` and ``(O,)`` (``O`` may be 0).
    polygons
        Vertices ``(V, 2)`` of every static polygon obstacle.
    """

    def __init__(self, name: str, data: dict[str, np.ndarray], scenario: object | None) -> None:
        self.name = name
        self.t = data["t"]
        self.states = data["states"]
        self.ids = [int(i) for i in data["ids"]]
        self.references = data.get("references")
        self.horizons = data.get("horizons")
        if scenario is not None:
            self.diameters = np.asarray(scenario.diameters(), dtype=float)  # type: ignore[attr-defined]
            obstacles = tuple(getattr(scenario, "obstacles", ()) or ())
            self.obstacle_diameters = np.array([o.diameter for o in obstacles], dtype=float)
            self.obstacle_positions = (np.stack([o.position_at(self.t) for o in obstacles], 1)
                                       if obstacles else np.zeros((self.t.size, 0, 2)))
            if self.references is None:
                self.references = np.asarray(scenario.reference_positions(self.t))  # type: ignore[attr-defined]
            self.polygons = [np.asarray(p.points, dtype=float)
                             for p in tuple(getattr(scenario, "polygons", ()) or ())]
        else:
            if "diameters" not in data:
                raise ProblemError("trajectory.npz has no 'diameters' (written by an older "
                                   "version): give the scenario with --scenario")
            self.diameters = data["diameters"]
            self.obstacle_diameters = data.get("obstacle_diameters", np.zeros(0))
            self.obstacle_positions = data.get("obstacle_positions",
                                               np.zeros((self.t.size, 0, 2)))
            sizes = data.get("polygon_sizes", np.zeros(0, dtype=np.int64))
            points = data.get("polygon_points", np.zeros((0, 2)))
            self.polygons = np.split(points, np.cumsum(sizes)[:-1]) if sizes.size else []
        if self.diameters.shape != (len(self.ids),):
            raise ProblemError(f"the scenario has {self.diameters.size} robots, the run "
                               f"{len(self.ids)}")

    @property
    def k(self) -> int:
        """Samples simulated (``len(t) - 1``)."""
        return int(self.t.size - 1)


def load_run(run_dir: str | os.PathLike[str], scenario: str | None = None) -> RunData:
    """Read a run folder (and the scenario, a file or built-in name, if given).

    Raises
    ------
    ProblemError
        The folder has no readable ``trajectory.npz`` or lacks what is needed.
    """
    import json

    from sqpmpc.problem.scenario_file import load_scenario

    run = Path(run_dir)
    path = run / "trajectory.npz"
    if not path.is_file():
        raise ProblemError(f"{run}: no trajectory.npz (not a run folder?)")
    try:
        data = load_trajectory(path)
    except (OSError, ValueError) as exc:
        raise ProblemError(f"{path}: cannot read it: {exc}") from exc
    name = run.name
    try:
        metrics = json.loads((run / "metrics.json").read_text())
        name = f"{metrics['scenario']}, {metrics['scheme']}"
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return RunData(name, data, load_scenario(scenario) if scenario else None)


def _limits(run: RunData) -> tuple[float, float, float, float]:
    pts = [run.states[..., :2].reshape(-1, 2)]
    if run.references is not None:
        pts.append(run.references.reshape(-1, 2))
    if run.obstacle_positions.size:
        pts.append(run.obstacle_positions.reshape(-1, 2))
    pts += [np.asarray(p).reshape(-1, 2) for p in run.polygons]
    p = np.concatenate(pts)
    p = p[np.isfinite(p).all(axis=1)]
    pad = float(run.diameters.max()) + 0.2
    lo, hi = p.min(axis=0) - pad, p.max(axis=0) + pad
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def _min_clearance(run: RunData) -> np.ndarray:
    """Smallest robot-robot clearance over the pairs at every sample (inf: one robot)."""
    n = len(run.ids)
    if n < 2:
        return np.full(run.t.size, np.inf)
    a, b = np.triu_indices(n, 1)
    pos = run.states[..., :2]
    dist = np.linalg.norm(pos[:, a] - pos[:, b], axis=-1)
    return (dist - 0.5 * (run.diameters[a] + run.diameters[b])).min(axis=1)


_MARGINS = (0.75, 0.2, 1.05, 0.6)  # left, right, bottom (x label, legend), top (title), in


def frame_size(run: RunData, height: float = 6.4, dpi: int = 100) -> tuple[float, float]:
    """Figure size (inches) whose plot area has the aspect of the run's extent, so the
    arena fills the frame; width and height are whole, even numbers of pixels."""
    x0, x1, y0, y1 = _limits(run)
    aspect = (x1 - x0) / max(y1 - y0, 1e-9)
    left, right, bottom, top = _MARGINS
    plot = height - bottom - top
    width = left + right + min(max(plot * aspect, 0.8 * plot), 2.0 * plot)

    def even(inches: float) -> float:
        return 2 * round(inches * dpi / 2) / dpi

    return even(width), even(height)


def _legend(fig: Figure, obstacles: bool) -> None:
    """What the marks mean, in one row under the plot."""
    from matplotlib.lines import Line2D

    grey = "0.35"
    handles = [
        Line2D([], [], ls="", marker="o", ms=10, mfc=(0.6, 0.6, 0.6, 0.35), mec=grey,
               label="robot (id, heading)"),
        Line2D([], [], color=grey, lw=1.2, label="driven path"),
        Line2D([], [], color=grey, marker=".", lw=1.0, ms=5, label="plan (horizon)"),
        Line2D([], [], color=grey, ls="", marker="x", ms=6, mew=1.6,
               label="reference now (goal)"),
        Line2D([], [], color=grey, ls=(0, (4, 3)), lw=0.8, label="reference path"),
    ]
    if obstacles:
        handles.append(Line2D([], [], ls="", marker="o", ms=10, mfc="0.6", mec="0.25",
                              label="obstacle"))
    fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 0.0), ncols=3,
               fontsize="small", frameon=False, borderaxespad=0.2)


def render_frames(run: RunData, step: int, size: tuple[float, float] | None = None,
                  dpi: int = 100, samples: list[int] | None = None) -> Iterator[np.ndarray]:
    """RGB frames ``(H, W, 3)`` uint8 of samples ``0, step, 2 step, ...`` and the last one
    (or of the given ``samples``); ``size`` in inches, default :func:`frame_size`."""
    # matplotlib is imported here, not with the module: the command line (every robot and
    # plant process parses it) starts without it
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle, Polygon

    n = len(run.ids)
    colors = robot_rgba(n)
    width, height = size or frame_size(run, dpi=dpi)
    fig = Figure(figsize=(width, height), dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    left, right, bottom, top = _MARGINS  # fixed margins: the plot takes all the rest
    ax = fig.add_axes((left / width, bottom / height, 1 - (left + right) / width,
                       1 - (bottom + top) / height))
    _legend(fig, bool(len(run.obstacle_diameters)))
    x0, x1, y0, y1 = _limits(run)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="box")
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if run.references is not None:
        for j in range(n):
            ax.plot(run.references[:, j, 0], run.references[:, j, 1], ls=(0, (4, 3)), lw=0.8,
                    color=colors[j], alpha=0.45)
    trails = [ax.plot([], [], "-", lw=1.2, color=colors[j], alpha=0.7)[0] for j in range(n)]
    plans = [ax.plot([], [], ".-", lw=1.0, ms=3.5, color=colors[j], zorder=4)[0]
             for j in range(n)]
    refs = [ax.plot([], [], "x", ms=6, mew=1.6, color=colors[j], zorder=5)[0]
            for j in range(n)]
    bodies = [ax.add_patch(Circle((0.0, 0.0), 0.5 * d, facecolor=c[:3] + (0.35,),
                                  edgecolor=c, lw=1.5, zorder=6))
              for d, c in zip(run.diameters, colors, strict=True)]
    headings = [ax.plot([], [], "-", lw=1.8, color="0.1", zorder=7)[0] for _ in range(n)]
    labels = [ax.text(0.0, 0.0, str(rid), fontsize=7, ha="center", va="center", zorder=8)
              for rid in run.ids]
    obstacles = [ax.add_patch(Circle((0.0, 0.0), 0.5 * d, facecolor="0.6", edgecolor="0.25",
                                     zorder=3))
                 for d in run.obstacle_diameters]
    for points in run.polygons:
        ax.add_patch(Polygon(points, closed=True, facecolor="0.6", edgecolor="0.25", zorder=3))
    title = ax.set_title("", fontsize="medium")
    clearance = np.minimum.accumulate(_min_clearance(run))
    frames = list(range(0, run.k + 1, step)) if samples is None else samples
    if samples is None and frames[-1] != run.k:
        frames.append(run.k)
    for k in frames:
        pos = run.states[k]
        for j in range(n):
            trails[j].set_data(run.states[: k + 1, j, 0], run.states[: k + 1, j, 1])
            r = 0.5 * run.diameters[j]
            x, y, psi = pos[j]
            bodies[j].set_center((x, y))
            headings[j].set_data([x, x + r * math.cos(psi)], [y, y + r * math.sin(psi)])
            labels[j].set_position((x - 0.45 * r * math.cos(psi), y - 0.45 * r * math.sin(psi)))
            if run.horizons is not None and k < run.horizons.shape[0]:
                plan = run.horizons[k, j]
                plans[j].set_data(plan[:, 0], plan[:, 1])
            else:
                plans[j].set_data([], [])
            if run.references is not None:
                refs[j].set_data([run.references[k, j, 0]], [run.references[k, j, 1]])
        for o, patch in enumerate(obstacles):
            patch.set_center(tuple(run.obstacle_positions[k, o]))
        low = "" if not np.isfinite(clearance[k]) else \
            f"\nsmallest clearance so far {clearance[k] * 1e3:.1f} mm"
        title.set_text(f"{run.name}: t = {run.t[k]:.1f} s (sample {k}/{run.k}){low}")
        canvas.draw()
        yield np.asarray(canvas.buffer_rgba())[..., :3].copy()


def frame_count(run: RunData, step: int) -> int:
    """How many frames :func:`render_frames` draws with ``step``: samples ``0, step, ...``
    and the last one."""
    return len(range(0, run.k + 1, step)) + (run.k % step != 0)


def animate(run: RunData, out: str | os.PathLike[str], fps: float = 10.0,
            step: int | None = None,
            progress: Callable[[int, int], None] | None = None) -> tuple[Path, int]:
    """Write the animation of ``run`` to ``out`` (``.gif`` or ``.mp4``).

    ``progress(done, total)``, if given, is called after each frame drawn (the command
    prints a line every few seconds from it).

    Returns
    -------
    (Path, int)
        The file written and its number of frames.

    Raises
    ------
    ProblemError
        Bad ``fps``/``step``, an unknown suffix, or ``.mp4`` without imageio-ffmpeg.
    """
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ProblemError(f"--out: expected a .gif or .mp4 file, got {str(out)!r}")
    if not (math.isfinite(fps) and fps > 0):
        raise ProblemError(f"--fps: expected a number > 0, got {fps!r}")
    if step is None:
        step = max(1, math.ceil((run.k + 1) / MAX_FRAMES))
    if step < 1:
        raise ProblemError(f"--step: expected an integer >= 1, got {step!r}")
    out.parent.mkdir(parents=True, exist_ok=True)
    frames = render_frames(run, step)
    if progress is not None:
        total = frame_count(run, step)
        frames = _reporting(frames, total, progress)
    if suffix == ".mp4":
        try:
            import imageio_ffmpeg
        except ImportError as exc:
            raise ProblemError("--out: writing .mp4 needs the imageio-ffmpeg package (pip "
                               "install imageio-ffmpeg); a .gif always works") from exc
        first = next(frames)
        h, w = first.shape[:2]
        writer = imageio_ffmpeg.write_frames(str(out), (w, h), fps=fps, macro_block_size=1)
        writer.send(None)
        count = 0
        try:
            for frame in (first, *frames):
                writer.send(np.ascontiguousarray(frame))
                count += 1
        finally:
            writer.close()
        return out, count
    from PIL import Image

    images = [Image.fromarray(f).quantize(colors=64, method=Image.Quantize.MEDIANCUT)
              for f in frames]
    images[0].save(out, save_all=True, append_images=images[1:],
                   duration=max(20, round(1000.0 / fps)), loop=0)
    return out, len(images)


def _reporting(frames: Iterator[np.ndarray], total: int,
               progress: Callable[[int, int], None]) -> Iterator[np.ndarray]:
    for done, frame in enumerate(frames, 1):
        yield frame
        progress(done, total)


def write_frame(run: RunData, sample: int, out: str | os.PathLike[str]) -> Path:
    """Write the frame of ``sample`` as a PNG (full colour)."""
    from PIL import Image

    if not 0 <= sample <= run.k:
        raise ProblemError(f"--frame: expected a sample in 0..{run.k}, got {sample}")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(next(render_frames(run, 1, samples=[sample]))).save(out, format="png")
    return out


