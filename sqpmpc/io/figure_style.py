"""Shared look of the run figures (:mod:`sqpmpc.io.plots`, :mod:`sqpmpc.io.fleetplots`):
colours, line styles, legends, titles, figure creation and saving."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from sqpmpc.sim.record import RunRecord

__all__ = ["CLEARANCE_LINTHRESH", "DPI"]

CLEARANCE_LINTHRESH = 1e-3
"""Clearance axis: linear within +-1 mm, logarithmic beyond (millimetres show)."""

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


