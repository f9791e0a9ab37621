r"""Figures that stay legible for fleets (dozens of robots), beside :mod:`sqpmpc.io.plots`.

- :func:`plot_clearance` (``clearance.png``): the fleet's smallest clearance
  over time, :math:`\min_{j<l} c_{jl}(t_i)`, with the pair that was closest
  named (robot ids) at its lowest moments, and every robot's clearance to its
  nearest neighbour (one curve per robot up to :data:`FEW` robots, a heat map
  of robots against time beyond).
- :func:`plot_paths_by_robot` (``paths_by_robot.png``): one small panel per
  robot (small multiples), its path coloured by time against its reference,
  on shared axes, one colour bar for time: laps and detours read in order.
- :func:`fleet_clearances`, :func:`nearest_clearances`: the numbers drawn.

Figures with one curve per robot switch to aggregates or heat maps past
:data:`FEW` robots, so that no legend has more entries than a reader can match.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.colors import LogNorm, Normalize
from matplotlib.figure import Figure

from sqpmpc.io.figure_style import (
    CLEARANCE_LINTHRESH,
    DPI,
    _colors,
    _legend,
    _new_figure,
    _save,
    _style,
    _title,
)
from sqpmpc.io.metrics import pair_distances
from sqpmpc.sim.record import RunRecord

__all__ = ["FEW", "fleet_clearances", "heat_map", "nearest_clearances", "plot_clearance",
           "plot_paths_by_robot", "time_marks"]

FEW = 8
"""Up to this many robots a figure draws one curve per robot (with a legend)."""
_LABELS = 6  # closest pairs named on the fleet's clearance curve, at most


def fleet_clearances(record: RunRecord) -> tuple[np.ndarray, np.ndarray] | None:
    """The fleet's smallest clearance at every sample and the pair it belongs to.

    Returns
    -------
    tuple of np.ndarray or None
        ``(clearance (k+1,), pair (k+1, 2))``, the pair as robot ids; ``None``
        for a single robot.
    """
    pairs = np.asarray(record.scenario.pairs(), dtype=np.int64).reshape(-1, 2)
    if pairs.shape[0] == 0:
        return None
    required = np.asarray(record.scenario.required_distances(), dtype=float)
    clear = pair_distances(record.positions, pairs) - required[pairs[:, 0], pairs[:, 1]]
    closest = np.argmin(clear, axis=1)
    ids = record.ids
    return clear[np.arange(clear.shape[0]), closest], ids[pairs[closest]]


def nearest_clearances(record: RunRecord) -> tuple[np.ndarray, np.ndarray] | None:
    """Every robot's clearance to its nearest neighbour at every sample, and who it is.

    Returns
    -------
    tuple of np.ndarray or None
        ``(clearance (k+1, n), neighbour id (k+1, n))``; ``None`` for a single robot.
    """
    n = record.positions.shape[1]
    if n < 2:
        return None
    pos = record.positions
    required = np.asarray(record.scenario.required_distances(), dtype=float)
    gaps = np.linalg.norm(pos[:, :, None, :] - pos[:, None, :, :], axis=-1) - required
    gaps[:, np.arange(n), np.arange(n)] = np.inf
    nearest = np.argmin(gaps, axis=2)
    clear = np.take_along_axis(gaps, nearest[..., None], axis=2)[..., 0]
    return clear, record.ids[nearest]


def time_marks(t: np.ndarray, marks: int = 10) -> tuple[np.ndarray, float]:
    """Indices of the samples at a round time step giving about ``marks`` marks, and the step."""
    span = float(t[-1] - t[0]) if t.size > 1 else 0.0
    if span <= 0.0:
        return np.zeros(1, dtype=np.int64), 0.0
    raw = span / marks
    scale = 10.0 ** math.floor(math.log10(raw))
    step = next(m * scale for m in (1.0, 2.0, 5.0, 10.0) if m * scale >= raw)
    dt = float(t[1] - t[0])
    every = max(1, round(step / dt))
    return np.arange(0, t.size, every), every * dt


def heat_map(ax: Axes, record: RunRecord, values: np.ndarray, label: str, cmap: str,
             norm: Normalize | None = None, times: np.ndarray | None = None) -> None:
    """One row per robot (by id, top to bottom), time along x, a colour bar labelled."""
    t = record.t if times is None else times
    ids = record.ids
    n = values.shape[1]
    if values.shape[0] == 0:
        ax.text(0.5, 0.5, "no sample yet", ha="center", va="center", transform=ax.transAxes)
        return
    t_hi = t[-1] + (t[1] - t[0] if t.size > 1 else 1.0)
    image = ax.imshow(values.T, aspect="auto", interpolation="nearest", cmap=cmap, norm=norm,
                      extent=(float(t[0]), float(t_hi), n - 0.5, -0.5))
    step = max(1, int(math.ceil(n / 16)))
    ax.set_yticks(np.arange(0, n, step), [str(int(i)) for i in ids[::step]])
    ax.set_ylabel("robot id")
    ax.figure.colorbar(image, ax=ax, label=label, pad=0.01)


def _fleet_curve(ax: Axes, record: RunRecord) -> None:
    """The fleet's smallest clearance, the closest pairs named at their lowest moments."""
    found = fleet_clearances(record)
    if found is None:
        ax.text(0.5, 0.5, "single robot: no pair", ha="center", va="center",
                transform=ax.transAxes)
        return
    clear, pair = found
    t = record.t
    ax.plot(t, clear, color="0.15", lw=1.3, marker="." if t.size < 3 else None,
            label="smallest clearance in the fleet")
    ax.set_yscale("symlog", linthresh=CLEARANCE_LINTHRESH, linscale=1.0)
    ax.axhline(0.0, color="tab:red", lw=1.2, label="touching (0)")
    # segments in which the same pair is the closest: name the lowest few
    change = np.flatnonzero(np.any(pair[1:] != pair[:-1], axis=1)) + 1
    bounds = np.concatenate([[0], change, [t.size]])
    lows = [(float(clear[a:b].min()), a + int(np.argmin(clear[a:b])))
            for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    lows.sort()
    gap = 0.04 * float(t[-1] - t[0])  # labels closer than this in time would overlap
    chosen: list[tuple[float, int]] = []
    for value, i in lows:
        if len(chosen) < _LABELS and all(abs(t[i] - t[c]) > gap for _, c in chosen):
            chosen.append((value, i))
    for rank, (value, i) in enumerate(sorted(chosen, key=lambda x: x[1])):
        a, b = (int(v) for v in pair[i])
        ax.annotate(f"{a}-{b}", (t[i], value), xytext=(0, 14 if rank % 2 else -16),
                    textcoords="offset points", ha="center", fontsize="x-small",
                    color="tab:blue", arrowprops={"arrowstyle": "-", "color": "tab:blue",
                                                  "lw": 0.6})
    value, i = lows[0]
    a, b = (int(v) for v in pair[i])
    ax.plot(t[i], value, "o", ms=11, mfc="none", mec="tab:red", mew=2.0, zorder=9,
            label="smallest of the run")
    ax.annotate(f"min {value * 1e3:.3g} mm at t = {t[i]:.3g} s, robots {a} and {b}",
                (t[i], value), xytext=(0.02, 0.9), textcoords="axes fraction",
                fontsize="small", arrowprops={"arrowstyle": "->", "color": "tab:red"},
                bbox={"boxstyle": "round", "fc": "w", "ec": "tab:red"})
    ax.set_ylabel("clearance [m] (symlog)")
    from matplotlib.lines import Line2D

    handles, _ = ax.get_legend_handles_labels()
    handles.append(Line2D([], [], color="tab:blue", lw=0.6, label="a-b: the closest pair "
                                                                   "(ids) at its lowest"))
    ax.legend(handles=handles, loc="best", fontsize="small")


def plot_clearance(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """The fleet's smallest clearance with who was closest, and each robot's nearest gap.

    Top: :math:`\\min_{j<l} c_{jl}(t_i)` on a symmetric-log axis (linear within
    1 mm), the closest pair's ids written at its lowest moments (at most six),
    the run's minimum circled. Bottom: every robot's clearance to its nearest
    neighbour: one curve per robot up to :data:`FEW` robots, else a heat map
    (rows: robots by id; colour: clearance, logarithmic from 1 mm).

    Returns
    -------
    Path
        The PNG written.
    """
    n = len(record.ids)
    fig, (top, low) = _new_figure(10.0, 7.5, rows=2)
    _fleet_curve(top, record)
    found = nearest_clearances(record)
    if found is None:
        low.text(0.5, 0.5, "single robot: no neighbour", ha="center", va="center",
                 transform=low.transAxes)
    elif n <= FEW:
        clear = found[0]
        for j, (rid, c) in enumerate(zip(record.ids, _colors(n), strict=True)):
            style = _style(j, n, clear.shape[0]) if clear.shape[0] > 1 else {"marker": "."}
            low.plot(record.t, clear[:, j], color=c, label=f"robot {rid}", **style)
        low.set_yscale("symlog", linthresh=CLEARANCE_LINTHRESH, linscale=1.0)
        low.axhline(0.0, color="tab:red", lw=1.2)
        low.set_ylabel("clearance to the nearest\nneighbour [m] (symlog)")
        _legend(low, n, outside=True)
    else:
        clear = found[0]
        hi = max(float(np.nanmax(clear)), 2 * CLEARANCE_LINTHRESH)
        heat_map(low, record, np.clip(clear, CLEARANCE_LINTHRESH, None),
                 "clearance to the nearest neighbour [m]", "viridis",
                 LogNorm(CLEARANCE_LINTHRESH, hi))
    low.set_xlabel("time [s]")
    for ax in (top, low):
        ax.grid(True, alpha=0.3, which="both")
    top.set_title(_title(record, "the fleet's smallest clearance and each robot's nearest "
                                 "neighbour"))
    return _save(fig, path)


def plot_paths_by_robot(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """One panel per robot: its path coloured by time, its reference, start and goal.

    Panels share their axes (the whole fleet's extent), so where each robot went
    reads at a glance; the colour bar gives the time. Legible up to 64 robots
    (an 8 x 8 grid).

    Returns
    -------
    Path
        The PNG written.
    """
    ids = record.ids
    n = len(ids)
    cols = max(1, int(math.ceil(math.sqrt(n))))
    rows = int(math.ceil(n / cols))
    side = 2.6 if n <= 16 else 1.6
    width, height = cols * side + 1.6, rows * side + 1.0
    # a fixed grid (no constrained layout: it takes seconds per figure at 64 panels)
    fig = Figure(figsize=(width, height), dpi=DPI)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    right = 1.0 - 1.3 / width
    # the same limits on every panel, set by hand (shared axes cost O(n^2) at 64 panels)
    axes = fig.subplots(rows, cols, squeeze=False, gridspec_kw={
        "left": 0.55 / width, "right": right, "bottom": 0.45 / height,
        "top": 1.0 - 0.7 / height, "wspace": 0.12, "hspace": 0.28}).ravel()
    pos, ref, t = record.positions, record.references(), record.t
    everything = np.concatenate([pos.reshape(-1, 2), ref.reshape(-1, 2)])
    lo, hi = everything.min(axis=0), everything.max(axis=0)
    pad = 0.05 * float(max(hi - lo)) + 0.1
    norm = Normalize(float(t[0]), float(max(t[-1], t[0] + 1e-9)))
    small = "x-small" if n > 16 else "small"
    from matplotlib.ticker import MaxNLocator

    xticks = MaxNLocator(4).tick_values(lo[0] - pad, hi[0] + pad)
    yticks = MaxNLocator(4).tick_values(lo[1] - pad, hi[1] + pad)
    xticks = xticks[(xticks >= lo[0] - pad) & (xticks <= hi[0] + pad)]
    yticks = yticks[(yticks >= lo[1] - pad) & (yticks <= hi[1] + pad)]
    for j, ax in enumerate(axes):
        if j >= n:
            ax.set_axis_off()
            continue
        ax.set_autoscale_on(False)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        if j % cols:
            ax.tick_params(labelleft=False)
        if j + cols < n:
            ax.tick_params(labelbottom=False)
        ax.plot(ref[:, j, 0], ref[:, j, 1], ls=(0, (2, 2)), color="0.55", lw=0.8)
        if t.size > 1:
            seg = np.stack([pos[:-1, j], pos[1:, j]], axis=1)
            lines = LineCollection(seg, cmap="viridis", norm=norm, lw=1.6)
            lines.set_array(0.5 * (t[:-1] + t[1:]))
            ax.add_collection(lines, autolim=False)
        ax.plot(*pos[0, j], "o", mfc="none", mec="k", ms=5)
        ax.plot(*ref[-1, j], "*", color="tab:red", ms=8, mec="k", mew=0.4)
        # a text, not a title (a title's placement measures every tick: slow at 64 panels)
        ax.text(0.5, 1.01, f"robot {ids[j]}", fontsize=small, ha="center", va="bottom",
                transform=ax.transAxes)
        ax.set_aspect("equal", adjustable="box")
        ax.set_xticks(xticks)
        ax.set_yticks(yticks)
        ax.tick_params(labelsize="x-small")
        ax.grid(True, alpha=0.3)
    from matplotlib.cm import ScalarMappable

    bar = fig.add_axes((right + 0.25 / width, 0.15, 0.2 / width, 0.7))
    fig.colorbar(ScalarMappable(norm=norm, cmap="viridis"), cax=bar, label="time [s]")
    fig.suptitle(_title(record, "each robot's path coloured by time (o start, * goal, "
                                "dashed: reference)"), fontsize="medium")
    return _save(fig, path)
