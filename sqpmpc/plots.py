r"""Figures of a run: the seed paper's Figures 1 to 6 for one scheme.

- :func:`plot_trajectories` (Fig. 1/2): every robot's path :math:`p_j(t_i)` in
  the x-y plane against its reference :math:`r_j(t_i)` (dashed), with start
  and end markers, equal aspect.
- :func:`plot_distances` (Fig. 3/4): the pairwise centre distances
  :math:`D_{jl}(t_i) = \lVert p_j(t_i) - p_l(t_i) \rVert` over time, with each
  distinct required distance :math:`(d_j + d_l)/2` as a horizontal line.
- :func:`plot_inputs` (Fig. 5/6): :math:`v_j` and :math:`\omega_j` over time as
  step plots (zero-order hold on :math:`[t_i, t_{i+1})`) with dashed bounds.

Figures are built with :class:`matplotlib.figure.Figure` directly and saved
through the Agg canvas, so no pyplot state, GUI backend or ``show`` is
involved and nothing needs closing. Drawing is vectorized over samples (the
only Python loops run over robots), so 8 robots x 2400 samples is quick.
Partial records (down to ``k = 0``) are drawn as far as they go.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from .metrics import RunRecord, pair_distances

__all__ = ["plot_distances", "plot_inputs", "plot_run", "plot_trajectories"]

log = logging.getLogger(__name__)

DPI = 120
_MANY_SERIES = 12  # legends with more entries go outside the axes, in columns


def _colors(n: int) -> list[tuple[float, float, float, float]]:
    """One distinct colour per robot (tab10, then tab20 for larger fleets)."""
    from matplotlib import colormaps

    cmap = colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(j % cmap.N) for j in range(n)]


def _new_figure(width: float, height: float, rows: int = 1) -> tuple[Figure, list[Axes]]:
    fig = Figure(figsize=(width, height), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    return fig, list(axes)


def _title(record: RunRecord, what: str) -> str:
    partial = "" if record.completed else f" (partial: {record.k}/{record.scenario.steps} steps)"
    return f"{record.scenario.name}, {record.scheme}: {what}{partial}"


def _legend(ax: Axes, entries: int, outside: bool = False) -> None:
    if outside or entries > _MANY_SERIES:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small",
                  ncols=max(1, int(np.ceil(entries / 24))), frameon=False)
    else:
        ax.legend(loc="best", fontsize="small")


def _save(fig: Figure, path: str | os.PathLike[str]) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    fig.clear()
    return path


def plot_trajectories(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Paths of every robot in the x-y plane against their references (Fig. 1/2).

    Solid line: executed path; dashed, same colour: reference over the same
    sample times; circle: start; cross: last sample.

    Returns
    -------
    Path
        The PNG written.
    """
    fig, (ax,) = _new_figure(7.0, 6.0)
    pos = record.positions
    ref = record.references()
    ids = record.ids
    colors = _colors(len(ids))
    for j, rid in enumerate(ids):
        c = colors[j]
        ax.plot(ref[:, j, 0], ref[:, j, 1], "--", color=c, lw=1.0, alpha=0.8)
        ax.plot(pos[:, j, 0], pos[:, j, 1], "-", color=c, lw=1.6, label=f"robot {rid}")
        ax.plot(pos[0, j, 0], pos[0, j, 1], "o", color=c, ms=6)
        ax.plot(pos[-1, j, 0], pos[-1, j, 1], "x", color=c, ms=7, mew=2)
    handles, _ = ax.get_legend_handles_labels()
    handles += [
        Line2D([], [], ls="--", color="0.4", label="reference"),
        Line2D([], [], ls="", marker="o", color="0.4", label="start"),
        Line2D([], [], ls="", marker="x", mew=2, color="0.4", label="end"),
    ]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              fontsize="small", frameon=False)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.set_title(_title(record, "trajectories"))
    return _save(fig, path)


def _pair_label(a: int, b: int) -> str:
    sub = f"{a}{b}" if a < 10 and b < 10 else f"{a},{b}"
    return f"$D_{{{sub}}}$"


def plot_distances(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Pairwise centre distances over time with the required distances (Fig. 3/4).

    One line per pair, labelled :math:`D_{jl}` by robot ids; each distinct
    required distance :math:`(d_j + d_l)/2` is drawn as a dashed horizontal
    line. A single robot has no pair: the figure then says so.

    Returns
    -------
    Path
        The PNG written.
    """
    sc = record.scenario
    ids = record.ids
    pairs = np.asarray(sc.pairs(), dtype=np.int64).reshape(-1, 2)
    fig, (ax,) = _new_figure(9.0, 5.0)
    if pairs.shape[0] == 0:
        ax.text(0.5, 0.5, "single robot: no pairwise distances", ha="center", va="center",
                transform=ax.transAxes)
    else:
        dist = pair_distances(record.positions, pairs)  # (k+1, P)
        required = np.asarray(sc.required_distances(), dtype=float)[pairs[:, 0], pairs[:, 1]]
        cmap_name = "tab10" if pairs.shape[0] <= 10 else "tab20"
        from matplotlib import colormaps

        cmap = colormaps[cmap_name]
        ax.set_prop_cycle(color=[cmap(i % cmap.N) for i in range(pairs.shape[0])])
        marker = "." if record.k == 0 else None
        lines = ax.plot(record.t, dist, lw=1.2, marker=marker)
        for i, (line, (a, b)) in enumerate(zip(lines, pairs, strict=True)):
            line.set_label(_pair_label(int(ids[a]), int(ids[b])))
            if i >= cmap.N:  # colours repeat: tell the pairs apart by line style
                line.set_linestyle("-." if (i // cmap.N) % 2 else ":")
        levels = np.unique(np.round(required, 12))
        styles = ("--", (0, (1, 1)), "-.")
        for i, value in enumerate(levels):
            ax.axhline(value, color="k", ls=styles[i % len(styles)], lw=1.2,
                       label=f"required {value:.3g} m")
        _legend(ax, pairs.shape[0] + len(levels))
        ax.set_ylim(bottom=0.0)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("centre distance [m]")
    ax.grid(True, alpha=0.3)
    ax.set_title(_title(record, "pairwise distances"))
    return _save(fig, path)


def _bound_line(ax: Axes, value: float, label: str | None) -> None:
    if np.isfinite(value):
        ax.axhline(value, color="k", ls="--", lw=1.0, label=label)


def plot_inputs(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    r"""Inputs :math:`v` and :math:`\omega` of every robot over time (Fig. 5/6).

    Two stacked panels, step plots (input ``i`` held on :math:`[t_i, t_{i+1})`),
    dashed lines at the input bounds.

    Returns
    -------
    Path
        The PNG written.
    """
    sc = record.scenario
    ids = record.ids
    lo = np.asarray(sc.bounds.input_lower(), dtype=float).reshape(2)
    hi = np.asarray(sc.bounds.input_upper(), dtype=float).reshape(2)
    colors = _colors(len(ids))
    fig, axes = _new_figure(9.0, 6.5, rows=2)
    names = ("v [m/s]", r"$\omega$ [rad/s]")
    k = record.k
    for c, ax in enumerate(axes):
        if k > 0:
            # Repeat the last input so the final hold interval [t_{k-1}, t_k] is drawn.
            held = np.concatenate([record.inputs[:, :, c], record.inputs[-1:, :, c]], axis=0)
            for j, rid in enumerate(ids):
                ax.step(record.t, held[:, j], where="post", color=colors[j], lw=1.2,
                        label=f"robot {rid}")
        else:
            ax.text(0.5, 0.5, "no input applied yet", ha="center", va="center",
                    transform=ax.transAxes)
        _bound_line(ax, lo[c], "bounds")
        _bound_line(ax, hi[c], None if np.isfinite(lo[c]) else "bounds")
        ax.set_ylabel(names[c])
        ax.grid(True, alpha=0.3)
    if k > 0 or np.isfinite(np.concatenate([lo, hi])).any():
        _legend(axes[0], len(ids) + 1, outside=True)
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title(_title(record, "inputs"))
    return _save(fig, path)


def plot_run(record: RunRecord, out_dir: str | os.PathLike[str]) -> list[Path]:
    """Write ``trajectories.png``, ``distances.png`` and ``inputs.png`` into ``out_dir``.

    Returns
    -------
    list of Path
        The files written, in that order.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = [
        plot_trajectories(record, out / "trajectories.png"),
        plot_distances(record, out / "distances.png"),
        plot_inputs(record, out / "inputs.png"),
    ]
    log.debug("wrote plots %s", [str(p) for p in written])
    return written
