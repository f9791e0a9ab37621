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

from sqpmpc.io.metrics import pair_distances
from sqpmpc.sim.record import RunRecord

__all__ = [
    "CLEARANCE_LINTHRESH",
    "plot_distances",
    "plot_inputs",
    "plot_run",
    "plot_solve_times",
    "plot_tracking",
    "plot_trajectories",
]

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


_STYLES = ("-", "--", "-.", ":")
_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*", "<", ">", "h", "p")


def _style(j: int, n: int, samples: int) -> dict[str, object]:
    """Line style of robot (or pair) ``j`` of ``n``: curves that coincide stay visible.

    Distinct dash patterns and markers, markers placed at staggered samples,
    and earlier curves drawn wider and lower, so a curve exactly on top of
    another leaves a rim of the one below.
    """
    every = max(1, samples // 10)
    return {"ls": _STYLES[j % len(_STYLES)], "marker": _MARKERS[j % len(_MARKERS)],
            "markevery": (min(samples - 1, (j * every) // max(n, 1)), every) if samples > 1
            else None, "ms": 5.0, "lw": 1.2 + 1.6 * (n - 1 - j) / max(n - 1, 1),
            "zorder": 2.0 + j / max(n, 1), "mfc": "none" if j % 2 else None}


def _obstacles(ax: Axes, record: RunRecord) -> None:
    """Obstacles at t = 0 (grey discs; a moving one also at the end, hatched, with its track)."""
    from matplotlib.patches import Circle

    t_end = float(record.t[-1])
    for o, ob in enumerate(getattr(record.scenario, "obstacles", ()) or ()):
        start = ob.position_at(0.0)
        ax.add_patch(Circle(tuple(start), 0.5 * ob.diameter, facecolor="0.6",
                            edgecolor="0.3", zorder=1.5,
                            label="obstacle" if o == 0 else None))
        if ob.moving:
            end = ob.position_at(t_end)
            ax.add_patch(Circle(tuple(end), 0.5 * ob.diameter, facecolor="none",
                                edgecolor="0.3", hatch="//", zorder=1.5))
            ax.plot([start[0], end[0]], [start[1], end[1]], ":", color="0.3", lw=1.0)


def plot_trajectories(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Paths of every robot in the x-y plane against their references (Fig. 1/2).

    Executed path: a line style and marker per robot (robots on symmetric
    paths stay distinguishable); thin dashed, same colour: reference over the
    same sample times; hollow circle of the robot's diameter: start; filled
    square: last sample; star: the reference at the last sample (the goal);
    arrows: headings at ten instants; grey discs: obstacles.

    Returns
    -------
    Path
        The PNG written.
    """
    from matplotlib.patches import Circle

    fig, (ax,) = _new_figure(8.0, 6.5)
    pos = record.positions
    ref = record.references()
    ids = record.ids
    n, samples = len(ids), pos.shape[0]
    colors = _colors(n)
    diameters = np.asarray(record.scenario.diameters(), dtype=float) if hasattr(
        record.scenario, "diameters") else np.full(n, 0.0)
    every = max(1, samples // 10)
    for j, rid in enumerate(ids):
        c = colors[j]
        ax.plot(ref[:, j, 0], ref[:, j, 1], ls=(0, (2, 2)), color=c, lw=0.9, alpha=0.7,
                zorder=1)
        ax.plot(pos[:, j, 0], pos[:, j, 1], color=c, label=f"robot {rid}",
                **_style(j, n, samples))
        ax.add_patch(Circle(tuple(pos[0, j]), 0.5 * diameters[j], fill=False, edgecolor=c,
                            lw=1.5, zorder=5))
        ax.plot(pos[-1, j, 0], pos[-1, j, 1], "s", color=c, ms=7, mec="k", zorder=6)
        ax.plot(ref[-1, j, 0], ref[-1, j, 1], "*", color=c, ms=12, mec="k", mew=0.6, zorder=6)
        head = record.states[::every, j]
        ax.quiver(head[:, 0], head[:, 1], np.cos(head[:, 2]), np.sin(head[:, 2]), color=c,
                  angles="xy", scale=28, width=0.004, zorder=4)
    _obstacles(ax, record)
    handles, _ = ax.get_legend_handles_labels()
    handles += [
        Line2D([], [], ls=(0, (2, 2)), color="0.4", label="reference"),
        Line2D([], [], ls="", marker="o", mfc="none", ms=9, color="0.4", label="start"),
        Line2D([], [], ls="", marker="s", mec="k", color="0.4", label="end"),
        Line2D([], [], ls="", marker="*", ms=11, mec="k", color="0.4", label="goal (ref. at end)"),
        Line2D([], [], ls="", marker=r"$\rightarrow$", ms=10, color="0.4", label="heading"),
    ]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              fontsize="small", frameon=False, ncols=max(1, int(np.ceil(len(handles) / 24))))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.set_title(_title(record, "trajectories"))
    return _save(fig, path)


def _pair_label(a: int, b: int) -> str:
    sub = f"{a}{b}" if a < 10 and b < 10 else f"{a},{b}"
    return f"$D_{{{sub}}}$"


CLEARANCE_LINTHRESH = 1e-3
"""Clearance axis: linear within +-1 mm, logarithmic beyond (millimetres show)."""


def plot_distances(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Pairwise centre distances and clearances over time (Fig. 3/4 and a zoom).

    Top: one curve per pair, labelled :math:`D_{jl}` by robot ids, with a
    line style and marker each; each distinct required distance
    :math:`(d_j + d_l)/2` is a black horizontal line. Bottom: the clearances
    :math:`D_{jl} - (d_j + d_l)/2` on a symmetric-log axis (linear within
    :data:`CLEARANCE_LINTHRESH`, so a millimetre is visible next to metres),
    zero in red, the smallest clearance marked and annotated. A single robot
    has no pair: the figure then says so.

    Returns
    -------
    Path
        The PNG written.
    """
    sc = record.scenario
    ids = record.ids
    pairs = np.asarray(sc.pairs(), dtype=np.int64).reshape(-1, 2)
    fig, axes = _new_figure(9.5, 7.5, rows=2)
    ax, low = axes
    P, samples = pairs.shape[0], record.t.size
    if P == 0:
        ax.text(0.5, 0.5, "single robot: no pairwise distances", ha="center", va="center",
                transform=ax.transAxes)
    else:
        dist = pair_distances(record.positions, pairs)  # (k+1, P)
        required = np.asarray(sc.required_distances(), dtype=float)[pairs[:, 0], pairs[:, 1]]
        clear = dist - required
        colors = _colors(P)
        for i, (a, b) in enumerate(pairs):
            style = _style(i, P, samples) if samples > 1 else {"marker": "."}
            label = _pair_label(int(ids[a]), int(ids[b]))
            ax.plot(record.t, dist[:, i], color=colors[i], label=label, **style)
            low.plot(record.t, clear[:, i], color=colors[i], **style)
        levels = np.unique(np.round(required, 12))
        styles = ("--", (0, (1, 1)), "-.")
        for i, value in enumerate(levels):
            ax.axhline(value, color="k", ls=styles[i % len(styles)], lw=1.2,
                       label=f"required {value:.3g} m")
        _legend(ax, P + len(levels), outside=True)
        ax.set_ylim(bottom=0.0)
        low.set_yscale("symlog", linthresh=CLEARANCE_LINTHRESH, linscale=1.0)
        low.axhline(0.0, color="tab:red", lw=1.2, label="touching (0)")
        k, i = np.unravel_index(int(np.argmin(clear)), clear.shape)
        a, b = pairs[i]
        value = float(clear[k, i])
        low.plot(record.t[k], value, "o", ms=11, mfc="none", mec="tab:red", mew=2.0, zorder=9,
                 label="smallest clearance")
        low.annotate(f"min {value * 1e3:.2f} mm\nt = {record.t[k]:.1f} s, robots "
                     f"{int(ids[a])}-{int(ids[b])}", (record.t[k], value),
                     xytext=(0.6, 0.12), textcoords="axes fraction", fontsize="small",
                     arrowprops={"arrowstyle": "->", "color": "tab:red"},
                     bbox={"boxstyle": "round", "fc": "w", "ec": "tab:red"})
        low.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small",
                   frameon=False)
    ax.set_ylabel("centre distance [m]")
    low.set_ylabel("clearance [m] (symlog: linear within 1 mm)")
    low.set_xlabel("time [s]")
    for a in axes:
        a.grid(True, alpha=0.3, which="both")
    ax.set_title(_title(record, "pairwise distances and clearances"))
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


def plot_tracking(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    r"""Tracking error :math:`\lVert p_j(t_i) - r_j(t_i) \rVert` and heading :math:`\psi_j`.

    Two stacked panels over time, one curve per robot (line style and marker
    each); the heading is wrapped to :math:`(-\pi, \pi]`, with breaks at the wraps.

    Returns
    -------
    Path
        The PNG written.
    """
    ids = record.ids
    n, samples = len(ids), record.t.size
    colors = _colors(n)
    fig, (err_ax, psi_ax) = _new_figure(9.5, 6.5, rows=2)
    err = np.linalg.norm(record.positions - record.references(), axis=-1)
    psi = np.angle(np.exp(1j * record.states[..., 2]))
    jumps = np.abs(np.diff(psi, axis=0)) > np.pi
    for j, rid in enumerate(ids):
        style = _style(j, n, samples) if samples > 1 else {"marker": "."}
        err_ax.plot(record.t, err[:, j], color=colors[j], label=f"robot {rid}", **style)
        heading = psi[:, j].copy()
        heading[1:][jumps[:, j]] = np.nan  # no vertical line across a wrap
        psi_ax.plot(record.t, heading, color=colors[j], **style)
    err_ax.set_ylabel("tracking error [m]")
    err_ax.set_ylim(bottom=0.0)
    psi_ax.set_ylabel(r"heading $\psi$ [rad]")
    psi_ax.set_yticks(np.pi * np.array([-1.0, -0.5, 0.0, 0.5, 1.0]),
                      [r"$-\pi$", r"$-\pi/2$", "0", r"$\pi/2$", r"$\pi$"])
    psi_ax.set_xlabel("time [s]")
    for ax in (err_ax, psi_ax):
        ax.grid(True, alpha=0.3)
    _legend(err_ax, n, outside=True)
    err_ax.set_title(_title(record, "tracking error and heading"))
    return _save(fig, path)


def plot_solve_times(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Controller computation time per sample against the sample-time budget.

    One curve per controller (the central one, or each robot) on a log axis
    in ms, its median as a dotted line of the same colour, the sum over the
    robots (the decentralized scheme's Table 3 convention) in grey, and the
    budget :math:`T_s` as a red line; the largest time is annotated.

    Returns
    -------
    Path
        The PNG written.
    """
    ts_ms = float(record.scenario.sample_time) * 1e3
    st = record.solve_times * 1e3  # (k, c)
    fig, (ax,) = _new_figure(9.5, 5.0)
    if record.k == 0:
        ax.text(0.5, 0.5, "no controller step yet", ha="center", va="center",
                transform=ax.transAxes)
    else:
        t = record.t[:-1]
        c = st.shape[1]
        names = ["central"] if c == 1 else [f"robot {i}" for i in record.ids]
        colors = _colors(c)
        for j, name in enumerate(names):
            med = float(np.median(st[:, j]))
            ax.plot(t, st[:, j], color=colors[j], lw=0.9, alpha=0.85,
                    label=f"{name} (median {med:.2f} ms, max {st[:, j].max():.2f} ms)")
            ax.axhline(med, color=colors[j], ls=":", lw=1.2)
        if c > 1:
            total = st.sum(axis=1)
            ax.plot(t, total, color="0.35", lw=1.0,
                    label=f"sum over robots (median {np.median(total):.2f} ms)")
        ax.axhline(ts_ms, color="tab:red", lw=1.6, label=f"budget $T_s$ = {ts_ms:g} ms")
        k, j = np.unravel_index(int(np.argmax(st)), st.shape)
        ax.annotate(f"max {st[k, j]:.2f} ms ({100 * st[k, j] / ts_ms:.2g} % of $T_s$)",
                    (t[k], st[k, j]), xytext=(0.02, 0.78), textcoords="axes fraction",
                    fontsize="small", arrowprops={"arrowstyle": "->", "color": "0.3"})
        ax.set_yscale("log")
        _legend(ax, c + 2, outside=True)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("computation per sample [ms]")
    ax.grid(True, alpha=0.3, which="both")
    ax.set_title(_title(record, "controller time against the sample time"))
    return _save(fig, path)


def plot_run(record: RunRecord, out_dir: str | os.PathLike[str]) -> list[Path]:
    """Write the figures of a run into ``out_dir``.

    ``trajectories.png``, ``distances.png`` and ``inputs.png`` (the paper's
    figures), ``tracking.png`` and ``solve_time.png``.

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
        plot_tracking(record, out / "tracking.png"),
        plot_solve_times(record, out / "solve_time.png"),
    ]
    log.debug("wrote plots %s", [str(p) for p in written])
    return written
