r"""The community's MAPF benchmark format: MovingAI ``.map`` and ``.scen`` files.

A ``.map`` file (Sturtevant, *Benchmarks for Grid-Based Pathfinding*, 2012;
https://movingai.com/benchmarks/mapf.html) is a header ``type octile``,
``height H``, ``width W``, ``map`` and ``H`` lines of ``W`` characters: ``.``,
``G`` and ``S`` are passable, ``@``, ``O``, ``T`` and ``W`` are not. A ``.scen``
file is ``version 1`` and one agent per line, nine tab-separated fields: bucket,
map file, width, height, start column, start row, goal column, goal row, optimal
length.

:func:`mapf_scenario` turns a map (and the first ``K`` agents of a ``.scen``
file, or ``K`` random distinct free cells) into a scenario: cell ``(column,
row)`` becomes the square of side ``cell`` centred at
:math:`((c + \tfrac12) h, (H - r - \tfrac12) h)` (row 0 at the top, as the file
reads), runs of blocked cells are merged into rectangles (each row's runs, joined
with the identical runs of the rows below), the map's outline bounds the robots'
centres (``[bounds]`` ``x``, ``y`` at one radius inside it), and the scenario
declares its grid (``[roadmap]``), so that the coordination layer plans on
exactly the map's cells.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import shortest_path

from sqpmpc.errors import ProblemError
from sqpmpc.problem.grid import grid_edges
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import parse_scenario

__all__ = ["blocked_rectangles", "mapf_scenario", "read_map", "read_scen"]

_PASSABLE = frozenset(".GS")
_BLOCKED = frozenset("@OTW")


def read_map(path: str | Path) -> np.ndarray:
    """The ``(H, W)`` bool array of blocked cells of a MovingAI ``.map`` file.

    Raises
    ------
    ProblemError
        Unreadable file, a bad header or a row of the wrong length or with unknown
        characters (the message names the file and the line).
    """
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ProblemError(f"{path}: cannot read the map: {exc}") from None
    header: dict[str, str] = {}
    body = 0
    for number, line in enumerate(lines[:5], start=1):
        word, _, value = line.strip().partition(" ")
        if word == "map":
            body = number
            break
        header[word] = value.strip()
    height, width = header.get("height", ""), header.get("width", "")
    if not body or not height.isdigit() or not width.isdigit() or "type" not in header:
        raise ProblemError(f"{path}: not a MovingAI map: expected the header 'type octile', "
                           "'height H', 'width W', 'map' in its first lines")
    h, w = int(height), int(width)
    rows = lines[body:body + h]
    if len(rows) != h or h == 0 or w == 0:
        raise ProblemError(f"{path}: expected {h} map rows after 'map', found {len(rows)}")
    blocked = np.zeros((h, w), dtype=bool)
    for r, row in enumerate(rows):
        row = row.rstrip("\r\n")
        bad = set(row) - _PASSABLE - _BLOCKED
        if len(row) != w or bad:
            what = f"unknown characters {sorted(bad)}" if bad else f"{len(row)} characters"
            raise ProblemError(f"{path}: line {body + r + 1}: expected {w} characters of "
                               f"'.GS@OTW', found {what}")
        blocked[r] = [c in _BLOCKED for c in row]
    return blocked


def read_scen(path: str | Path) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """The agents of a MovingAI ``.scen`` file: ``((start column, start row), (goal column,
    goal row))`` each, in file order.

    Raises
    ------
    ProblemError
        Unreadable file or a malformed line (named).
    """
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ProblemError(f"{path}: cannot read the scenario: {exc}") from None
    if not lines or not lines[0].startswith("version"):
        raise ProblemError(f"{path}: not a MovingAI scenario: expected 'version 1' on line 1")
    agents = []
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        fields = line.split("\t") if "\t" in line else line.split()
        try:
            sx, sy, gx, gy = (int(v) for v in fields[4:8])
        except (ValueError, IndexError):
            raise ProblemError(f"{path}: line {number}: expected 9 fields (bucket, map, width, "
                               "height, start x, start y, goal x, goal y, length)") from None
        agents.append(((sx, sy), (gx, gy)))
    return agents


def blocked_rectangles(blocked: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Blocked cells merged into rectangles ``(row0, col0, row1, col1)`` (half-open): each
    row's runs, each joined with the identical runs of the following rows."""
    h, w = blocked.shape
    open_runs: dict[tuple[int, int], int] = {}  # (col0, col1) -> first row
    out: list[tuple[int, int, int, int]] = []
    for r in range(h + 1):
        runs: set[tuple[int, int]] = set()
        if r < h:
            row = blocked[r]
            c = 0
            while c < w:
                if row[c]:
                    start = c
                    while c < w and row[c]:
                        c += 1
                    runs.add((start, c))
                else:
                    c += 1
        for run in [k for k in open_runs if k not in runs]:
            out.append((open_runs.pop(run), run[0], r, run[1]))
        for run in runs:
            open_runs.setdefault(run, r)
    return sorted(out)


def _cell_centre(col: int, row: int, height: int, cell: float) -> tuple[float, float]:
    return ((col + 0.5) * cell, (height - row - 0.5) * cell)


def _grid_distances(blocked: np.ndarray, sources: list[int]) -> np.ndarray:
    h, w = blocked.shape
    free = ~blocked.ravel()
    edges = grid_edges((h, w))
    edges = edges[free[edges[:, 0]] & free[edges[:, 1]]]
    graph = coo_matrix((np.ones(edges.shape[0]), (edges[:, 0], edges[:, 1])),
                       shape=(h * w, h * w)).tocsr()
    return np.asarray(shortest_path(graph, directed=False, unweighted=True, indices=sources))


def mapf_scenario(map_path: str | Path, robots: int, *, scen_path: str | Path | None = None,
                  cell: float = 1.0, diameter: float = 0.3, v_max: float = 1.0,
                  omega_max: float = math.pi / 2, acceleration: float | None = None,
                  angular_acceleration: float | None = None, sample_time: float = 0.2,
                  horizon: int = 10, seed: int = 0, name: str | None = None) -> Scenario:
    """A scenario of ``robots`` robots on a MovingAI map (module docstring).

    Parameters
    ----------
    map_path
        The ``.map`` file.
    robots
        ``K``: the first ``K`` agents of ``scen_path``, or ``K`` random distinct free start
        and goal cells (seeded by ``seed``) without one.
    cell
        Cell size :math:`h`, m.
    diameter
        Robot diameter, m.
    v_max, omega_max
        Bounds of :math:`|v|` (m/s) and :math:`|\\omega|` (rad/s).
    acceleration, angular_acceleration
        Bounds of :math:`|a|` and :math:`|\\alpha|` (both or neither), m/s^2 and rad/s^2.
    sample_time, horizon
        :math:`T_s` and :math:`N`.
    name
        Scenario name (default: the map's stem and ``K``).

    Raises
    ------
    ProblemError
        Unreadable files, too few agents or free cells, a start or goal on a blocked
        cell or outside the map, a goal that cannot be reached from its start, a
        robot wider than a cell, or only one of the acceleration bounds.
    """
    blocked = read_map(map_path)
    height, width = blocked.shape
    if isinstance(robots, bool) or not isinstance(robots, int) or robots < 1:
        raise ProblemError(f"robots must be a positive integer, got {robots!r}")
    for key, value in (("cell", cell), ("diameter", diameter), ("v_max", v_max),
                       ("omega_max", omega_max)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ProblemError(f"{key} must be a finite number > 0, got {value!r}")
    if diameter >= cell:
        raise ProblemError(f"diameter {diameter:g} m does not fit a cell of {cell:g} m: robots "
                           "on neighbouring cells would touch (use a larger --cell)")
    if (acceleration is None) != (angular_acceleration is None):
        raise ProblemError("give both acceleration and angular_acceleration, or neither")
    if scen_path is not None:
        agents = read_scen(scen_path)
        if len(agents) < robots:
            raise ProblemError(f"{scen_path}: {robots} robots asked, the file has "
                               f"{len(agents)} agents")
        agents = agents[:robots]
        for k, ((sx, sy), (gx, gy)) in enumerate(agents):
            for what, (x, y) in (("start", (sx, sy)), ("goal", (gx, gy))):
                if not (0 <= x < width and 0 <= y < height) or blocked[y, x]:
                    raise ProblemError(f"{scen_path}: agent {k + 1}: {what} ({x}, {y}) is "
                                       "outside the map or on a blocked cell")
    else:
        free = np.flatnonzero(~blocked.ravel())
        if free.size < robots:
            raise ProblemError(f"{map_path}: {robots} robots asked, the map has {free.size} "
                               "free cells")
        rng = np.random.default_rng(seed)
        starts = rng.choice(free, robots, replace=False)
        goals = rng.choice(free, robots, replace=False)
        agents = [((int(s % width), int(s // width)), (int(g % width), int(g // width)))
                  for s, g in zip(starts, goals, strict=True)]
    start_cells = [s[1] * width + s[0] for s, _ in agents]
    goal_cells = [g[1] * width + g[0] for _, g in agents]
    for what, cells in (("start", start_cells), ("goal", goal_cells)):
        if len(set(cells)) != len(cells):
            raise ProblemError(f"two robots share a {what} cell")
    hops = _grid_distances(blocked, start_cells)[np.arange(robots), goal_cells]
    if not np.all(np.isfinite(hops)):
        k = int(np.argmax(~np.isfinite(hops)))
        raise ProblemError(f"robot {k + 1}: its goal cell {agents[k][1]} cannot be reached "
                           f"from its start cell {agents[k][0]}")
    longest = float(hops.max(initial=0.0)) * cell / v_max
    steps = max(1, math.ceil((3.0 * longest + 30.0) / sample_time))
    radius = 0.5 * diameter
    bounds: dict[str, object] = {
        "v": [-v_max, v_max], "omega": [-omega_max, omega_max],
        "x": [radius, width * cell - radius], "y": [radius, height * cell - radius]}
    if acceleration is not None:
        bounds["acceleration"] = [-acceleration, acceleration]
        bounds["angular_acceleration"] = [-angular_acceleration, angular_acceleration]
    obstacles = [{"points": [[c0 * cell, (height - r1) * cell], [c1 * cell, (height - r1) * cell],
                             [c1 * cell, (height - r0) * cell], [c0 * cell, (height - r0) * cell]]}
                 for r0, c0, r1, c1 in blocked_rectangles(blocked)]
    robot_tables = []
    for k, ((sx, sy), (gx, gy)) in enumerate(agents):
        start = _cell_centre(sx, sy, height, cell)
        goal = _cell_centre(gx, gy, height, cell)
        robot_tables.append({"id": k + 1, "initial_state": [start[0], start[1], 0.0],
                             "diameter": diameter,
                             "reference": {"type": "point", "position": list(goal)}})
    stem = Path(map_path).stem
    return parse_scenario({
        "name": name or f"{stem}-{robots}", "t_end": steps * sample_time,
        "sample_time": sample_time, "horizon": horizon,
        "weights": {"Q": [1.0, 1.0], "R": [0.5, 0.5]}, "bounds": bounds,
        "robots": robot_tables, "obstacles": obstacles,
        "roadmap": {"cell": cell, "origin": [0.5 * cell, 0.5 * cell]},
    }, source=f"<generated from {Path(map_path).name}>")
