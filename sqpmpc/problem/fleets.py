r"""Parametric fleet scenarios: antipodal swaps, random crossings, grid-to-grid formations.

Each generator returns a validated :class:`~sqpmpc.problem.scenario.Scenario` with
point references (a goal at rest), the paper's weights and input bounds, and
``t_end`` a multiple of the longest straight trip at full speed, rounded up to
a whole number of samples: three for swaps (measured makespans up to 2.2
trips), six for random crossings and grids, whose dense goal sets take up to
four (a 6x6 grid: 63.5 s for a 17.2 s trip). ``sqpmpc generate KIND ...`` writes them as
scenario files (:meth:`Scenario.to_toml`).

- :func:`antipodal_swap`: ``n`` robots evenly on a circle, each sent to the
  opposite point; the radius :math:`3\sqrt{n/6}` m keeps the density of the
  built-in ``swap-6`` (3 m for 6 robots), so every robot meets every other
  near the centre at the same time (the hardest symmetric encounter).
- :func:`random_crossings`: starts and goals drawn (seeded) in a square whose
  side keeps the same density, every pair at least ``spacing`` apart at both
  ends, headings towards the goals.
- :func:`grid_to_grid`: a ``rows x cols`` grid sent to a grid on the other side,
  mirrored, so that the two halves' paths cross.
"""

from __future__ import annotations

import math

import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import parse_scenario

__all__ = ["FLEET_KINDS", "MAX_ROBOTS", "antipodal_swap", "grid_to_grid", "random_crossings"]

#: Largest fleet a generator writes (the scenario loader's own limits apply too).
MAX_ROBOTS = 1024
#: ``sqpmpc generate`` kinds.
FLEET_KINDS = ("swap", "crossings", "grid")

_V_MAX = 0.6
_OMEGA_MAX = math.pi / 4


def _check_count(name: str, value: object, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or not (
            low <= value <= high):
        raise ProblemError(f"{name} must be an integer from {low} to {high}, got {value!r}")
    return int(value)


def _check_positive(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
            math.isfinite(value) and value > 0):
        raise ProblemError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


def _scenario(name: str, starts: np.ndarray, goals: np.ndarray, sample_time: float,
              horizon: int, diameter: float, trips: float = 6.0) -> Scenario:
    """The scenario of robots at ``starts (n, 3)`` with point goals ``goals (n, 2)``,
    ``t_end`` ``trips`` times the longest straight trip at full speed."""
    longest = float(np.max(np.hypot(*(goals - starts[:, :2]).T)))
    steps = max(1, math.ceil(trips * longest / _V_MAX / sample_time))
    return parse_scenario({
        "name": name, "t_end": steps * sample_time, "sample_time": sample_time,
        "horizon": horizon, "weights": {"Q": [1.0, 1.0], "R": [0.5, 0.5]},
        "bounds": {"v": [-_V_MAX, _V_MAX], "omega": [-_OMEGA_MAX, _OMEGA_MAX]},
        "robots": [{"id": i + 1, "initial_state": [float(v) for v in starts[i]],
                    "diameter": diameter,
                    "reference": {"type": "point", "position": [float(v) for v in goals[i]]}}
                   for i in range(starts.shape[0])],
    }, source=f"<generated {name}>")


def _heading(starts: np.ndarray, goals: np.ndarray) -> np.ndarray:
    d = goals - starts
    return np.arctan2(d[:, 1], d[:, 0])


def antipodal_swap(robots: int, sample_time: float = 0.5, horizon: int = 8,
                   diameter: float = 0.3) -> Scenario:
    r"""``robots`` on a circle of radius :math:`3\sqrt{n/6}` m, each sent to the opposite
    point, facing it (named ``swap-<n>``)."""
    n = _check_count("robots", robots, 2, MAX_ROBOTS)
    sample_time = _check_positive("sample_time", sample_time)
    diameter = _check_positive("diameter", diameter)
    radius = 3.0 * math.sqrt(n / 6.0)
    angle = 2.0 * np.pi * np.arange(n) / n
    xy = radius * np.stack((np.cos(angle), np.sin(angle)), axis=-1)
    xy = np.round(xy, 12) + 0.0  # -0.0 -> 0.0: the files stay readable
    goals = -xy + 0.0
    starts = np.column_stack((xy, _heading(xy, goals)))
    return _scenario(f"swap-{n}", starts, goals, sample_time,
                     _check_count("horizon", horizon, 1, 200), diameter, trips=3.0)


def _scatter(rng: np.random.Generator, n: int, side: float, spacing: float) -> np.ndarray:
    """``n`` points in a square of side ``side``, pairwise at least ``spacing`` apart."""
    points = np.empty((0, 2))
    for _ in range(200 * n):
        p = rng.uniform(-side / 2, side / 2, size=2)
        if points.shape[0] == 0 or np.min(np.hypot(*(points - p).T)) >= spacing:
            points = np.vstack((points, p))
            if points.shape[0] == n:
                return points
    raise ProblemError(f"cannot place {n} robots {spacing} m apart in a {side:.3g} m square; "
                       "lower spacing or robots")


def random_crossings(robots: int, seed: int, sample_time: float = 0.5, horizon: int = 8,
                     diameter: float = 0.3, spacing: float = 0.6) -> Scenario:
    """Random starts and goals (``seed``) at the density of ``swap-6``, named
    ``crossings-<n>-<seed>``."""
    n = _check_count("robots", robots, 2, MAX_ROBOTS)
    seed = _check_count("seed", seed, 0, 2**32 - 1)
    spacing = _check_positive("spacing", spacing)
    diameter = _check_positive("diameter", diameter)
    if spacing <= diameter:
        raise ProblemError(f"spacing must exceed the diameter ({diameter} m), got {spacing}")
    side = 6.0 * math.sqrt(n / 6.0)  # the swap's circle diameter at the same density
    rng = np.random.default_rng(seed)
    starts_xy = np.round(_scatter(rng, n, side, spacing), 6)
    goals = np.round(_scatter(rng, n, side, spacing), 6)
    starts = np.column_stack((starts_xy, _heading(starts_xy, goals)))
    return _scenario(f"crossings-{n}-{seed}", starts, goals,
                     _check_positive("sample_time", sample_time),
                     _check_count("horizon", horizon, 1, 200), diameter)


def grid_to_grid(rows: int, cols: int, spacing: float = 1.0, gap: float = 4.0,
                 sample_time: float = 0.5, horizon: int = 8, diameter: float = 0.3) -> Scenario:
    """A ``rows x cols`` grid (``spacing`` m) left of the origin sent to the mirrored grid
    ``gap`` m to its right: the top row goes to the bottom, so the flows cross
    (named ``grid-<rows>x<cols>``)."""
    rows = _check_count("rows", rows, 1, MAX_ROBOTS)
    cols = _check_count("cols", cols, 1, MAX_ROBOTS)
    _check_count("rows * cols", rows * cols, 2, MAX_ROBOTS)
    spacing = _check_positive("spacing", spacing)
    gap = _check_positive("gap", gap)
    diameter = _check_positive("diameter", diameter)
    if spacing <= diameter:
        raise ProblemError(f"spacing must exceed the diameter ({diameter} m), got {spacing}")
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    x = (c.ravel() - (cols - 1) / 2.0) * spacing
    y = (r.ravel() - (rows - 1) / 2.0) * spacing
    width = (cols - 1) * spacing
    starts_xy = np.column_stack((x - (width + gap) / 2.0, y))
    goals = np.column_stack((x + (width + gap) / 2.0, -y + 0.0))
    starts = np.column_stack((starts_xy, _heading(starts_xy, goals)))
    return _scenario(f"grid-{rows}x{cols}", starts, goals,
                     _check_positive("sample_time", sample_time),
                     _check_count("horizon", horizon, 1, 200), diameter)
