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
from collections.abc import Callable
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.lines import Line2D

from sqpmpc.io.figure_style import (
    CLEARANCE_LINTHRESH,
    _colors,
    _legend,
    _new_figure,
    _save,
    _style,
    _title,
)
from sqpmpc.io.fleetplots import (
    FEW,
    _fleet_curve,
    heat_map,
    plot_clearance,
    plot_paths_by_robot,
    time_marks,
)
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

def _obstacles(ax: Axes, record: RunRecord) -> None:
    """Obstacles at t = 0 (grey discs and polygons; a moving one also at the end, hatched,
    with its track)."""
    from matplotlib.patches import Circle, Polygon

    for o, poly in enumerate(getattr(record.scenario, "polygons", ()) or ()):
        ax.add_patch(Polygon(np.asarray(poly.points), closed=True, facecolor="0.6",
                             edgecolor="0.3", zorder=1.5,
                             label="wall / shelf" if o == 0 else None))
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

    Executed path: a line style per robot (robots on symmetric paths stay
    distinguishable; past :data:`~sqpmpc.io.fleetplots.FEW` robots plain lines,
    each robot's id written at its start instead of a legend entry); dots
    every round number of seconds (about ten, larger as time goes on): the time
    coding; thin dashed, same colour: reference over the same sample times;
    hollow circle of the robot's diameter: start; filled square: last sample;
    star: the reference at the last sample (the goal); arrows: headings at ten
    instants; grey discs: obstacles. ``paths_by_robot.png``
    (:func:`sqpmpc.io.fleetplots.plot_paths_by_robot`) has one panel per robot
    coloured by time.

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
    marks, step = time_marks(record.t)
    many = n > FEW
    for j, rid in enumerate(ids):
        c = colors[j]
        ax.plot(ref[:, j, 0], ref[:, j, 1], ls=(0, (2, 2)), color=c, lw=0.9, alpha=0.7,
                zorder=1)
        if many:  # plain lines, the id written at the start instead of 64 legend entries
            ax.plot(pos[:, j, 0], pos[:, j, 1], color=c, lw=1.0)
            ax.annotate(str(rid), tuple(pos[0, j]), xytext=(0, 7), textcoords="offset points",
                        ha="center", fontsize=6, color="0.1", zorder=7)
        else:
            ax.plot(pos[:, j, 0], pos[:, j, 1], color=c, label=f"robot {rid}",
                    **{**_style(j, n, samples), "marker": None})
        if step > 0:  # time coding: a dot every `step` seconds, larger as time goes on
            ax.scatter(pos[marks, j, 0], pos[marks, j, 1], s=6 + 30 * marks / marks[-1],
                       color=c, edgecolors="k", linewidths=0.4, zorder=3)
        ax.add_patch(Circle(tuple(pos[0, j]), 0.5 * diameters[j], fill=False, edgecolor=c,
                            lw=1.5, zorder=5))
        ax.plot(pos[-1, j, 0], pos[-1, j, 1], "s", color=c, ms=7, mec="k", zorder=6)
        ax.plot(ref[-1, j, 0], ref[-1, j, 1], "*", color=c, ms=12, mec="k", mew=0.6, zorder=6)
        if many:
            continue  # 64 heading arrows hide the paths (headings: tracking.png)
        head = record.states[::every, j]
        ax.quiver(head[:, 0], head[:, 1], np.cos(head[:, 2]), np.sin(head[:, 2]), color=c,
                  angles="xy", scale=28, width=0.004, zorder=4)
    _obstacles(ax, record)
    handles, _ = ax.get_legend_handles_labels()
    if step > 0:
        handles.append(Line2D([], [], ls="", marker="o", mec="k", color="0.4",
                              label=f"every {step:g} s (larger: later)"))
    handles += [
        Line2D([], [], ls=(0, (2, 2)), color="0.4", label="reference"),
        Line2D([], [], ls="", marker="o", mfc="none", ms=9, color="0.4", label="start"),
        Line2D([], [], ls="", marker="s", mec="k", color="0.4", label="end"),
        Line2D([], [], ls="", marker="*", ms=11, mec="k", color="0.4", label="goal (ref. at end)"),
    ]
    if not many:
        handles.append(Line2D([], [], ls="", marker=r"$\rightarrow$", ms=10, color="0.4",
                              label="heading"))
    else:
        handles.append(Line2D([], [], ls="", marker="$1$", color="0.1", label="robot id (start)"))
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




def plot_distances(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Pairwise centre distances and clearances over time (Fig. 3/4 and a zoom).

    Top: one curve per pair, labelled :math:`D_{jl}` by robot ids, with a
    line style and marker each; each distinct required distance
    :math:`(d_j + d_l)/2` is a black horizontal line. Bottom: the clearances
    :math:`D_{jl} - (d_j + d_l)/2` on a symmetric-log axis (linear within
    :data:`CLEARANCE_LINTHRESH`, so a millimetre is visible next to metres),
    zero in red, the smallest clearance marked and annotated. A single robot
    has no pair: the figure then says so. Past :data:`~sqpmpc.io.fleetplots.FEW`
    robots (28 pairs) the top panel shows the pairs' spread (closest pair, 5th to
    50th percentile) and the bottom one the fleet's smallest clearance with the
    closest pair's ids (:func:`sqpmpc.io.fleetplots.plot_clearance`).

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
    if len(ids) > FEW:  # every pair's curve would be a tangle: their spread, and the closest
        dist = pair_distances(record.positions, pairs)
        q = np.percentile(dist, [0, 5, 50], axis=1)
        ax.fill_between(record.t, q[1], q[2], color="tab:blue", alpha=0.25,
                        label="5th to 50th percentile of the pairs")
        ax.plot(record.t, q[0], color="tab:blue", lw=1.2, label="closest pair")
        required = np.asarray(sc.required_distances(), dtype=float)[pairs[:, 0], pairs[:, 1]]
        for value in np.unique(np.round(required, 12))[:3]:
            ax.axhline(value, color="k", ls="--", lw=1.0, label=f"required {value:.3g} m")
        ax.set_ylim(bottom=0.0)
        ax.legend(loc="upper right", fontsize="small")
        ax.set_ylabel(f"centre distance [m] ({P} pairs)")
        _fleet_curve(low, record)
        low.set_xlabel("time [s]")
        for a in axes:
            a.grid(True, alpha=0.3, which="both")
        ax.set_title(_title(record, "pairwise distances and the smallest clearance"))
        return _save(fig, path)
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
    a line style, width and marker per robot (robots with equal inputs stay
    visible), dashed lines at the input bounds; past
    :data:`~sqpmpc.io.fleetplots.FEW` robots a heat map per input (robots by id
    against time, the colour scale spanning the bounds).

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
    k, n = record.k, len(ids)
    if n > FEW and k > 0:  # a heat map per input: robots by id against time
        for c, ax in enumerate(axes):
            limit = float(np.nanmax(np.abs(np.concatenate([lo[c:c + 1], hi[c:c + 1]]))))
            limit = limit if np.isfinite(limit) and limit > 0 else None
            from matplotlib.colors import Normalize

            heat_map(ax, record, record.inputs[:, :, c], names[c], "coolwarm",
                     Normalize(-limit, limit) if limit else None, times=record.t[:-1])
        axes[-1].set_xlabel("time [s]")
        axes[0].set_title(_title(record, "inputs (red: at the upper bound, blue: lower)"))
        return _save(fig, path)
    for c, ax in enumerate(axes):
        if k > 0:
            # Repeat the last input so the final hold interval [t_{k-1}, t_k] is drawn.
            held = np.concatenate([record.inputs[:, :, c], record.inputs[-1:, :, c]], axis=0)
            for j, rid in enumerate(ids):
                style = _style(j, n, k + 1)  # robots with equal inputs stay visible
                ax.step(record.t, held[:, j], where="post", color=colors[j],
                        label=f"robot {rid}", **style)
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
    each); the heading is wrapped to :math:`(-\pi, \pi]`, with breaks at the wraps. Past
    :data:`~sqpmpc.io.fleetplots.FEW` robots, heat maps (robots by id against time).

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
    if n > FEW:
        heat_map(err_ax, record, err, "tracking error [m]", "magma_r")
        from matplotlib.colors import Normalize

        heat_map(psi_ax, record, psi, r"heading $\psi$ [rad]", "twilight",
                 Normalize(-np.pi, np.pi))
        psi_ax.set_xlabel("time [s]")
        err_ax.set_title(_title(record, "tracking error and heading"))
        return _save(fig, path)
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

    Centralized: the central controller's time. Decentralized: the sum over the
    robots (the paper's Table 3 convention, what ``solve_time`` in
    ``metrics.json`` reports), and per robot: one curve each up to
    :data:`~sqpmpc.io.fleetplots.FEW` robots, else the slowest and the median
    robot of each sample. Every label says which of these it is; medians are
    dotted lines of the same colour; the budget :math:`T_s` is a red line; the
    arrow points at the largest value of the curve the metrics report (the
    sum, or the central controller's time). Log axis in ms.

    With the record's CPU times (:attr:`RunRecord.cpu_times`) the curves are CPU
    time (thread time) and the wall time of the first curve is drawn dashed
    beside them; the title gives the load average at the run's end.

    Returns
    -------
    Path
        The PNG written.
    """
    ts_ms = float(record.scenario.sample_time) * 1e3
    cpu = record.cpu_times is not None
    st = (record.cpu_times if cpu else record.solve_times) * 1e3  # (k, c)
    fig, (ax,) = _new_figure(9.5, 5.0)
    if record.k == 0:
        ax.text(0.5, 0.5, "no controller step yet", ha="center", va="center",
                transform=ax.transAxes)
    else:
        t = record.t[:-1]
        c = st.shape[1]
        if c == 1:
            curves = [("central controller", st[:, 0], "tab:blue", 1.2)]
        elif c <= FEW:
            curves = [(f"robot {i}", st[:, j], color, 0.9)
                      for j, (i, color) in enumerate(zip(record.ids, _colors(c), strict=True))]
        else:
            curves = [("slowest robot of each sample", st.max(axis=1), "tab:orange", 1.0),
                      ("median robot of each sample", np.median(st, axis=1), "tab:green", 1.0)]
        if c > 1:
            curves.insert(0, (f"sum over the {c} robots", st.sum(axis=1), "0.2", 1.4))
        for name, values, color, lw in curves:
            med = float(np.median(values))
            ax.plot(t, values, color=color, lw=lw, alpha=0.9,
                    label=f"{name}: median {med:.3g} ms, max {values.max():.3g} ms")
            ax.axhline(med, color=color, ls=":", lw=1.0)
        if cpu:
            wall = record.solve_times * 1e3
            wall = wall[:, 0] if wall.shape[1] == 1 else wall.sum(axis=1)
            ax.plot(t, wall, color="0.5", lw=0.8, ls="--", alpha=0.8,
                    label=f"wall time of the {curves[0][0]}: median {np.median(wall):.3g} ms")
        ax.axhline(ts_ms, color="tab:red", lw=1.6, label=f"budget $T_s$ = {ts_ms:.3g} ms")
        name, values = curves[0][0], curves[0][1]
        k = int(np.argmax(values))
        ax.annotate(f"max of the {name.split(':')[0]}: {values[k]:.3g} ms "
                    f"({100 * values[k] / ts_ms:.3g} % of $T_s$)",
                    (t[k], values[k]), xytext=(0.02, 0.9), textcoords="axes fraction",
                    fontsize="small", arrowprops={"arrowstyle": "->", "color": "0.3"})
        ax.set_yscale("log")
        _legend(ax, len(curves) + 1 + cpu, outside=True)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{'CPU time' if cpu else 'computation'} per sample [ms]")
    ax.grid(True, alpha=0.3, which="both")
    load = record.extra.get("load_average")
    what = "controller CPU time (thread time)" if cpu else "controller time"
    if load:
        what += f", load {load[0]:.2f} at the end"
    ax.set_title(_title(record, f"{what} against the sample time"))
    return _save(fig, path)


def plot_run(record: RunRecord, out_dir: str | os.PathLike[str],
             progress: Callable[[Path, int, int], None] | None = None) -> list[Path]:
    """Write the figures of a run into ``out_dir``.

    ``trajectories.png``, ``distances.png`` and ``inputs.png`` (the paper's
    figures), ``tracking.png``, ``solve_time.png``, and for fleets
    ``clearance.png`` and ``paths_by_robot.png`` (:mod:`sqpmpc.io.fleetplots`).
    ``progress(path, done, total)``, if given, is called after each figure.

    Returns
    -------
    list of Path
        The files written, in that order.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figures = [(plot_trajectories, "trajectories.png"), (plot_distances, "distances.png"),
               (plot_inputs, "inputs.png"), (plot_tracking, "tracking.png"),
               (plot_solve_times, "solve_time.png"), (plot_clearance, "clearance.png"),
               (plot_paths_by_robot, "paths_by_robot.png")]
    written = []
    for draw, name in figures:
        written.append(draw(record, out / name))
        if progress is not None:
            progress(written[-1], len(written), len(figures))
    log.debug("wrote plots %s", [str(p) for p in written])
    return written
