"""Scenarios: the robots, their references, weights, bounds and timing of a run.

A scenario is read from a TOML file or a built-in name (the ``*.toml`` files of
package :mod:`sqpmpc.scenarios`, by stem: ``paper-s1``, ``paper-s2``) and fully
validated before anything runs; every problem is one
:class:`~sqpmpc.errors.ScenarioError` naming the file, the key (e.g.
``robots[2].diameter``, with robots indexed from 0 in file order), the robot's
id when it has one (``robot id 3 (the 3rd [[robots]] table)``) and what was
expected.

The problem it describes: robots :math:`j = 1..n` with unicycle states
:math:`(x_j, y_j, \\psi_j)` and inputs :math:`u_j = (v_j, \\omega_j)` minimize

.. math::

    \\sum_j \\sum_{i=1}^{N} \\lVert r_j(t_{k+i}) - p_{j,k+i} \\rVert_Q^2
    + \\sum_{i=0}^{N-1} \\lVert u_{j,k+i} \\rVert_R^2,
    \\qquad Q = \\operatorname{diag}(Q), \\; R = \\operatorname{diag}(R) \\succ 0,

subject to :math:`u_{\\min} \\le u \\le u_{\\max}`, optional position bounds and
:math:`\\lVert p_j - p_l \\rVert \\ge (d_j + d_l) / 2` for every pair, sampled
with :math:`T_s` = ``sample_time`` for :math:`K = t_{\\mathrm{end}} / T_s` steps.
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ProblemError, ScenarioError
from .obstacles import Obstacle
from .plant import PlantSpec
from .references import (
    Reference,
    _describe,
    _FieldError,
    _integer,
    _real,
    _real_vector,
    reference_from_dict,
)

__all__ = [
    "MAX_HORIZON",
    "MAX_ROBOTS",
    "MAX_ROBOT_SAMPLES",
    "MAX_STEPS",
    "MIN_SAMPLE_TIME",
    "Bounds",
    "RobotSpec",
    "Scenario",
    "Weights",
    "builtin_scenario_names",
    "load_scenario",
    "parse_scenario",
]

_PAIR = "an array of 2 finite numbers [lower, upper] with lower <= upper"
_STEPS_RTOL = 1e-9

# Limits on the numbers that size arrays and loops: checked before anything is allocated,
# so no scenario (file, built-in or override) can run for hours or exhaust memory.
MAX_HORIZON = 200
"""Largest ``horizon`` N accepted (the QPs grow with N; the paper uses 5 and 8)."""
MAX_STEPS = 1_000_000
"""Largest number of samples K = t_end / sample_time accepted."""
MAX_ROBOTS = 1024
"""Largest number of ``[[robots]]`` accepted."""
MIN_SAMPLE_TIME = 1e-4
"""Smallest ``sample_time`` accepted, s."""
MAX_ROBOT_SAMPLES = 10_000_000
"""Largest number of robots times samples K accepted (a run's trajectory: 240 MB)."""


def _pair(value: Any, key: str, unit: str) -> tuple[float, float]:
    lower, upper = _real_vector(value, 2, key, f"{_PAIR} ({unit})")
    if lower > upper:
        raise _FieldError(key, f"expected lower <= upper, found lower {lower!r} above upper "
                          f"{upper!r}")
    return lower, upper


@dataclass(frozen=True)
class Weights:
    """Diagonal cost weights.

    Parameters
    ----------
    Q
        Diagonal of :math:`Q` on the output :math:`(x, y)`, entries :math:`\\ge 0`.
    R
        Diagonal of :math:`R` on the input :math:`(v, \\omega)`, entries :math:`> 0`
        (:math:`R \\succ 0` as in the paper).
    """

    Q: tuple[float, float]
    R: tuple[float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "Q", _real_vector(
            self.Q, 2, "Q", "an array of 2 finite numbers >= 0 [q_x, q_y]", minimum=0.0))
        object.__setattr__(self, "R", _real_vector(
            self.R, 2, "R", "an array of 2 finite numbers > 0 [r_v, r_omega]",
            minimum=0.0, strict=True))


@dataclass(frozen=True)
class Bounds:
    """Inclusive box bounds on inputs and (optionally) positions.

    Parameters
    ----------
    v, omega
        ``(lower, upper)`` of the speed (m/s) and turn rate (rad/s).
    x, y
        Optional ``(lower, upper)`` of the position coordinates, m; ``None``
        means unbounded.
    """

    v: tuple[float, float]
    omega: tuple[float, float]
    x: tuple[float, float] | None = None
    y: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "v", _pair(self.v, "v", "m/s"))
        object.__setattr__(self, "omega", _pair(self.omega, "omega", "rad/s"))
        for name in ("x", "y"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _pair(value, name, "m"))

    def input_lower(self) -> np.ndarray:
        """:math:`u_{\\min} = (v_{\\min}, \\omega_{\\min})`, shape ``(2,)``."""
        return np.array([self.v[0], self.omega[0]])

    def input_upper(self) -> np.ndarray:
        """:math:`u_{\\max} = (v_{\\max}, \\omega_{\\max})`, shape ``(2,)``."""
        return np.array([self.v[1], self.omega[1]])

    def position_lower(self) -> np.ndarray:
        """Lower position bound ``(x, y)``, ``-inf`` where absent, shape ``(2,)``."""
        return np.array([b[0] if b is not None else -np.inf for b in (self.x, self.y)])

    def position_upper(self) -> np.ndarray:
        """Upper position bound ``(x, y)``, ``+inf`` where absent, shape ``(2,)``."""
        return np.array([b[1] if b is not None else np.inf for b in (self.x, self.y)])


@dataclass(frozen=True)
class RobotSpec:
    """One robot.

    Parameters
    ----------
    id
        Positive integer, unique in the scenario.
    initial_state
        :math:`(x, y, \\psi)` at :math:`t = 0`, m, m, rad.
    diameter
        :math:`d > 0`, m.
    reference
        The trajectory to track.
    """

    id: int
    initial_state: tuple[float, float, float]
    diameter: float
    reference: Reference

    def __post_init__(self) -> None:
        object.__setattr__(self, "id", _integer(self.id, "id", 1, "a positive integer"))
        object.__setattr__(self, "initial_state", _real_vector(
            self.initial_state, 3, "initial_state", "an array of 3 finite numbers [x, y, psi]"))
        object.__setattr__(self, "diameter", _real(
            self.diameter, "diameter", minimum=0.0, strict=True,
            what="a finite number > 0 (m)"))
        if not isinstance(self.reference, Reference):
            raise _FieldError("reference", "expected a HarmonicReference, PointReference or "
                              f"WaypointReference, found {_describe(self.reference)}")


def _check_name(value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise _FieldError("name", f"expected a non-empty string, found {_describe(value)}")
    if any(c in value for c in "/\\") or any(ord(c) < 32 or ord(c) == 127 for c in value):
        raise _FieldError("name", "expected a name without '/', '\\' or control characters "
                          f"(it names output folders), found {value!r}")
    return value


def _check_timing(t_end: Any, sample_time: Any, horizon: Any) -> tuple[float, float, int]:
    t_end = _real(t_end, "t_end", minimum=0.0, strict=True, what="a finite number > 0 (s)")
    ts = _real(sample_time, "sample_time", minimum=0.0, strict=True,
               what="a finite number > 0 (s)")
    if ts < MIN_SAMPLE_TIME:
        raise _FieldError("sample_time", f"expected at least {MIN_SAMPLE_TIME:g} s, found {ts!r}")
    horizon = _integer(horizon, "horizon", 1, "an integer >= 1")
    if horizon > MAX_HORIZON:
        raise _FieldError("horizon", f"expected at most {MAX_HORIZON}, found {horizon}")
    ratio = t_end / ts
    if not ratio <= MAX_STEPS + 0.5:  # also catches an overflow to inf
        raise _FieldError("t_end", f"expected at most {MAX_STEPS} samples (t_end / sample_time)"
                          f", found t_end = {t_end!r} s with sample_time = {ts!r} s")
    steps = round(ratio)
    if steps < 1 or abs(ratio - steps) > _STEPS_RTOL * ratio:
        raise _FieldError("t_end", f"expected a positive whole multiple of sample_time = {ts!r} "
                          f"s, found t_end = {t_end!r} s ({ratio:.10g} samples)")
    return t_end, ts, horizon


def _check_robot_count(source: str, count: int, steps: int) -> None:
    if count > MAX_ROBOTS:
        raise ScenarioError(source, "robots", f"expected at most {MAX_ROBOTS} robots, found "
                            f"{count}")
    if count * steps > MAX_ROBOT_SAMPLES:
        raise ScenarioError(source, "t_end", f"expected at most {MAX_ROBOT_SAMPLES} robot "
                            f"samples (robots x t_end / sample_time), found {count} robots x "
                            f"{steps} samples")


@dataclass(frozen=True)
class Scenario:
    """A validated scenario.

    Parameters
    ----------
    name
        Identifier used in outputs.
    t_end
        Simulated time :math:`t_{\\mathrm{end}}`, s; a whole multiple of ``sample_time``.
    sample_time
        :math:`T_s > 0`, s.
    horizon
        :math:`N \\ge 1`, prediction = control horizon.
    weights, bounds
        Cost weights and box bounds.
    robots
        At least one robot, unique ids, not overlapping at :math:`t = 0`.
    obstacles
        Circular obstacles (static or moving), none overlapping a robot at
        :math:`t = 0` (the file's ``[[obstacles]]``).
    plant
        How the simulated robots really move (the file's ``[plant]``; default:
        the Euler step, no noise).
    source
        File path or built-in name it came from (not part of equality).

    Raises
    ------
    ScenarioError
        On construction (and :meth:`with_changes`) when anything is invalid.
    """

    name: str
    t_end: float
    sample_time: float
    horizon: int
    weights: Weights
    bounds: Bounds
    robots: tuple[RobotSpec, ...]
    obstacles: tuple[Obstacle, ...] = ()
    plant: PlantSpec = field(default_factory=PlantSpec)
    source: str = field(default="<memory>", compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.source, str):
            object.__setattr__(self, "source", str(self.source))
        try:
            object.__setattr__(self, "name", _check_name(self.name))
            t_end, ts, horizon = _check_timing(self.t_end, self.sample_time, self.horizon)
        except _FieldError as exc:
            raise ScenarioError(self.source, exc.key, exc.detail) from None
        object.__setattr__(self, "t_end", t_end)
        object.__setattr__(self, "sample_time", ts)
        object.__setattr__(self, "horizon", horizon)
        for key, cls in (("weights", Weights), ("bounds", Bounds)):
            if not isinstance(getattr(self, key), cls):
                raise ScenarioError(self.source, key, f"expected a {cls.__name__}, found "
                                    f"{_describe(getattr(self, key))}")
        robots = self.robots
        if not isinstance(robots, list | tuple) or not robots:
            raise ScenarioError(self.source, "robots", "expected at least one robot "
                                f"([[robots]] tables), found {_describe(robots)}")
        robots = tuple(robots)
        _check_robot_count(self.source, len(robots), self.steps)
        for i, robot in enumerate(robots):
            if not isinstance(robot, RobotSpec):
                raise ScenarioError(self.source, f"robots[{i}]",
                                    f"expected a RobotSpec, found {_describe(robot)}")
        object.__setattr__(self, "robots", robots)
        self._check_robots()
        if not isinstance(self.obstacles, list | tuple):
            raise ScenarioError(self.source, "obstacles", "expected [[obstacles]] tables, found "
                                f"{_describe(self.obstacles)}")
        object.__setattr__(self, "obstacles", tuple(self.obstacles))
        for i, obstacle in enumerate(self.obstacles):
            if not isinstance(obstacle, Obstacle):
                raise ScenarioError(self.source, f"obstacles[{i}]",
                                    f"expected an Obstacle, found {_describe(obstacle)}")
        if not isinstance(self.plant, PlantSpec):
            raise ScenarioError(self.source, "plant", f"expected a PlantSpec ([plant] table), "
                                f"found {_describe(self.plant)}")
        self._check_obstacles()

    def _check_obstacles(self) -> None:
        xy = self.initial_states()[:, :2]
        for o, obstacle in enumerate(self.obstacles):
            gap = np.hypot(*(xy - np.asarray(obstacle.position)).T)
            need = 0.5 * (self.diameters() + obstacle.diameter)
            bad = np.flatnonzero(gap < need)
            if bad.size:
                j = int(bad[0])
                raise ScenarioError(
                    self.source, f"obstacles[{o}].position",
                    f"obstacle {o} overlaps robot id {self.robots[j].id} (robots[{j}]) at "
                    f"t = 0: centre distance {gap[j]:.6g} m, expected at least "
                    f"(d_robot + d_obstacle) / 2 = {need[j]:.6g} m")

    def _check_robots(self) -> None:
        first: dict[int, int] = {}
        for i, robot in enumerate(self.robots):
            if robot.id in first:
                raise ScenarioError(self.source, f"robots[{i}].id",
                                    f"expected a unique id, found {robot.id} already used by "
                                    f"robots[{first[robot.id]}] (robots[i] is the (i+1)-th "
                                    "[[robots]] table)")
            first[robot.id] = i
        lower, upper = self.bounds.position_lower(), self.bounds.position_upper()
        for i, robot in enumerate(self.robots):
            x, y = robot.initial_state[:2]
            if x < lower[0] or x > upper[0] or y < lower[1] or y > upper[1]:
                box = " and ".join(f"bounds.{k} = [{b[0]!r}, {b[1]!r}]" for k, b in
                                   (("x", self.bounds.x), ("y", self.bounds.y)) if b is not None)
                raise ScenarioError(
                    self.source, f"robots[{i}].initial_state",
                    f"expected an initial position inside {box}, found ({x!r}, {y!r}) "
                    f"(id {robot.id})")
        xy = self.initial_states()[:, :2]
        distance = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=-1)
        required = self.required_distances()
        for j, k in self.pairs():
            if distance[j, k] < required[j, k]:
                a, b = self.robots[j], self.robots[k]
                raise ScenarioError(
                    self.source, f"robots[{k}].initial_state",
                    f"robots id {a.id} (robots[{j}]) and id {b.id} (robots[{k}]) overlap at "
                    f"t = 0: centre distance {distance[j, k]:.6g} m, expected at least "
                    f"(d_{a.id} + d_{b.id}) / 2 = {required[j, k]:.6g} m")

    # -- derived data ---------------------------------------------------------------------

    @property
    def n_robots(self) -> int:
        """Number of robots :math:`n`."""
        return len(self.robots)

    @property
    def ids(self) -> np.ndarray:
        """Robot ids in file order, ``int64`` shape ``(n,)``."""
        return np.array([r.id for r in self.robots], dtype=np.int64)

    @property
    def steps(self) -> int:
        """Number of samples :math:`K = t_{\\mathrm{end}} / T_s`."""
        return round(self.t_end / self.sample_time)

    def initial_states(self) -> np.ndarray:
        """States at :math:`t = 0`, shape ``(n, 3)``."""
        return np.array([r.initial_state for r in self.robots], dtype=np.float64)

    def diameters(self) -> np.ndarray:
        """Diameters :math:`d_j`, shape ``(n,)``."""
        return np.array([r.diameter for r in self.robots], dtype=np.float64)

    def required_distances(self) -> np.ndarray:
        """:math:`D_{jl} = (d_j + d_l) / 2` for :math:`j \\ne l`, 0 on the diagonal; ``(n, n)``."""
        d = self.diameters()
        out = 0.5 * (d[:, None] + d[None, :])
        np.fill_diagonal(out, 0.0)
        return out

    def pairs(self) -> np.ndarray:
        """All index pairs :math:`(j, l)`, :math:`j < l`, row-major; ``int64`` ``(P, 2)``."""
        j, k = np.triu_indices(self.n_robots, 1)
        return np.stack((j, k), axis=-1).astype(np.int64)

    def reference_positions(self, t: float | np.ndarray) -> np.ndarray:
        """:math:`r_j(t)` of every robot, shape ``np.shape(t) + (n, 2)``."""
        return np.stack([r.reference.position(t) for r in self.robots], axis=-2)

    def reference_velocities(self, t: float | np.ndarray) -> np.ndarray:
        """:math:`\\dot r_j(t)` of every robot, shape ``np.shape(t) + (n, 2)``."""
        return np.stack([r.reference.velocity(t) for r in self.robots], axis=-2)

    def index_of(self, robot_id: int) -> int:
        """Index (file order) of the robot with id ``robot_id``.

        Raises
        ------
        ProblemError
            No robot has that id.
        """
        for i, robot in enumerate(self.robots):
            if robot.id == robot_id:
                return i
        raise ProblemError(f"no robot with id {robot_id!r} in scenario {self.name!r}; "
                           f"ids: {', '.join(str(r.id) for r in self.robots)}")

    def with_changes(self, **changes: Any) -> Scenario:
        """A copy with some fields replaced (``dataclasses.replace``), validated again."""
        return dataclasses.replace(self, **changes)

    def to_toml(self) -> str:
        """The scenario in the scenario-file format; :func:`load_scenario` reads it back."""
        lines = [f"name = {_toml_value(self.name)}",
                 f"t_end = {_toml_value(self.t_end)}",
                 f"sample_time = {_toml_value(self.sample_time)}",
                 f"horizon = {self.horizon}", "", "[weights]",
                 f"Q = {_toml_value(self.weights.Q)}",
                 f"R = {_toml_value(self.weights.R)}", "", "[bounds]"]
        for key in ("v", "omega", "x", "y"):
            value = getattr(self.bounds, key)
            if value is not None:
                lines.append(f"{key} = {_toml_value(value)}")
        for robot in self.robots:
            lines += ["", "[[robots]]", f"id = {robot.id}",
                      f"initial_state = {_toml_value(robot.initial_state)}",
                      f"diameter = {_toml_value(robot.diameter)}",
                      f"reference = {_toml_value(robot.reference.to_dict())}"]
        for obstacle in self.obstacles:
            lines += ["", "[[obstacles]]"]
            lines += [f"{k} = {_toml_value(v)}" for k, v in obstacle.to_dict().items()]
        if self.plant != PlantSpec():
            lines += ["", "[plant]"]
            lines += [f"{k} = {_toml_value(v)}" for k, v in self.plant.to_dict().items()]
        return "\n".join(lines) + "\n"


def _toml_value(value: Any) -> str:
    """TOML text of a string, int, float, array or inline table (finite values only)."""
    if isinstance(value, str):
        escaped = value.replace("\\", "\\\\").replace('"', '\\"')
        return f'"{escaped}"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} as TOML")


# -- parsing --------------------------------------------------------------------------------

_TOP_KEYS = ("name", "t_end", "sample_time", "horizon", "weights", "bounds", "robots")
_OPTIONAL_TOP_KEYS = ("obstacles", "plant")
_OBSTACLE_KEYS = ("position", "diameter", "velocity")
_OBSTACLE_REQUIRED = ("position", "diameter")
_PLANT_KEYS = ("model", "input_noise", "seed")
_WEIGHT_KEYS = ("Q", "R")
_BOUND_KEYS = ("v", "omega", "x", "y")
_BOUND_REQUIRED = ("v", "omega")
_ROBOT_KEYS = ("id", "initial_state", "diameter", "reference")
_EXPECTED = {  # what a missing key should hold
    "name": "a non-empty string",
    "t_end": "a finite number > 0 (s)",
    "sample_time": "a finite number > 0 (s)",
    "horizon": "an integer >= 1",
    "weights": "a [weights] table with Q and R",
    "bounds": "a [bounds] table with v and omega",
    "robots": "at least one [[robots]] table",
    "Q": "an array of 2 finite numbers >= 0 [q_x, q_y]",
    "R": "an array of 2 finite numbers > 0 [r_v, r_omega]",
    "v": "an array of 2 finite numbers [lower, upper] (m/s)",
    "omega": "an array of 2 finite numbers [lower, upper] (rad/s)",
    "id": "a positive integer",
    "initial_state": "an array of 3 finite numbers [x, y, psi]",
    "diameter": "a finite number > 0 (m)",
    "reference": "an inline table { type = ..., ... }",
    "position": "an array of 2 finite numbers [x, y] (m)",
}


def _table(value: Any, source: str, key: str, allowed: tuple[str, ...],
           required: tuple[str, ...]) -> Mapping[str, Any]:
    """Check a table's type, then unknown keys (in file order), then missing keys."""
    where = f"[{key}]" if key else "the scenario"
    if not isinstance(value, Mapping):
        raise ScenarioError(source, key, f"expected a table ({where}), found {_describe(value)}")
    prefix = f"{key}." if key else ""
    for name in value:
        if name not in allowed:
            raise ScenarioError(source, f"{prefix}{name}",
                                f"unknown key in {where}; allowed keys: {', '.join(allowed)}")
    for name in required:
        if name not in value:
            raise ScenarioError(source, f"{prefix}{name}",
                                f"missing required key in {where}; expected {_EXPECTED[name]}")
    return value


def _build(cls: type, source: str, prefix: str, **kwargs: Any) -> Any:
    try:
        return cls(**kwargs)
    except _FieldError as exc:
        raise ScenarioError(source, f"{prefix}.{exc.key}", exc.detail) from None


def parse_scenario(data: Mapping[str, Any], source: str = "<memory>") -> Scenario:
    """Validate a parsed scenario file (nested dicts as ``tomllib`` returns them).

    Parameters
    ----------
    data
        The top-level table.
    source
        File path or name used in error messages and stored as :attr:`Scenario.source`.

    Raises
    ------
    ScenarioError
        The first problem found, naming ``source`` and the key.
    """
    _table(data, source, "", _TOP_KEYS + _OPTIONAL_TOP_KEYS, _TOP_KEYS)
    try:  # top-level scalars first, so errors come roughly in file order
        _check_name(data["name"])
        t_end, ts, _ = _check_timing(data["t_end"], data["sample_time"], data["horizon"])
    except _FieldError as exc:
        raise ScenarioError(source, exc.key, exc.detail) from None
    w = _table(data["weights"], source, "weights", _WEIGHT_KEYS, _WEIGHT_KEYS)
    weights = _build(Weights, source, "weights", Q=w["Q"], R=w["R"])
    b = _table(data["bounds"], source, "bounds", _BOUND_KEYS, _BOUND_REQUIRED)
    bounds = _build(Bounds, source, "bounds", **b)
    raw_robots = data["robots"]
    if not isinstance(raw_robots, list | tuple) or not raw_robots:
        raise ScenarioError(source, "robots", "expected at least one [[robots]] table, found "
                            f"{_describe(raw_robots)}")
    _check_robot_count(source, len(raw_robots), round(t_end / ts))
    robots = []
    for i, raw in enumerate(raw_robots):
        key = f"robots[{i}]"
        try:
            r = _table(raw, source, key, _ROBOT_KEYS, _ROBOT_KEYS)
            reference = reference_from_dict(r["reference"], source, f"{key}.reference")
            robots.append(_build(RobotSpec, source, key, id=r["id"],
                                 initial_state=r["initial_state"], diameter=r["diameter"],
                                 reference=reference))
        except ScenarioError as exc:  # name the robot by its id, not only its table's index
            raise ScenarioError(source, exc.key, f"{_robot_label(raw, i)}: {exc.detail}") from None
    obstacles = []
    raw_obstacles = data.get("obstacles", [])
    if not isinstance(raw_obstacles, list | tuple):
        raise ScenarioError(source, "obstacles", "expected [[obstacles]] tables, found "
                            f"{_describe(raw_obstacles)}")
    for i, raw in enumerate(raw_obstacles):
        key = f"obstacles[{i}]"
        o = _table(raw, source, key, _OBSTACLE_KEYS, _OBSTACLE_REQUIRED)
        obstacles.append(_build_checked(Obstacle, source, key, **o))
    plant = PlantSpec()
    if "plant" in data:
        plant = _build_checked(PlantSpec, source, "plant",
                               **_table(data["plant"], source, "plant", _PLANT_KEYS, ()))
    return Scenario(name=data["name"], t_end=data["t_end"], sample_time=data["sample_time"],
                    horizon=data["horizon"], weights=weights, bounds=bounds,
                    robots=tuple(robots), obstacles=tuple(obstacles), plant=plant,
                    source=source)


def _robot_label(raw: Any, index: int) -> str:
    """``robot id 2 (the 2nd [[robots]] table)``, or the table alone without a valid id."""
    n = index + 1
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    table = f"the {n}{suffix} [[robots]] table"
    rid = raw.get("id") if isinstance(raw, dict) else None
    if isinstance(rid, int) and not isinstance(rid, bool) and rid > 0:
        return f"robot id {rid} ({table})"
    return table


def _build_checked(cls: type, source: str, prefix: str, **kwargs: Any) -> Any:
    """Build a dataclass whose validation raises :class:`ProblemError` naming the field."""
    try:
        return cls(**kwargs)
    except ProblemError as exc:
        field_name, _, detail = str(exc).partition(": ")  # "<field>: expected ..."
        if field_name in {f.name for f in dataclasses.fields(cls)}:
            raise ScenarioError(source, f"{prefix}.{field_name}", detail) from None
        raise ScenarioError(source, prefix, str(exc)) from None


# -- loading --------------------------------------------------------------------------------


def builtin_scenario_names() -> list[str]:
    """Names of the built-in scenarios (stems of ``sqpmpc/scenarios/*.toml``), sorted."""
    folder = resources.files("sqpmpc.scenarios")
    return sorted(p.name[:-5] for p in folder.iterdir()
                  if p.name.endswith(".toml") and p.is_file())


def _parse_text(raw: bytes, source: str) -> Scenario:
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise ScenarioError(source, "", f"cannot read: not UTF-8 text (byte {exc.start}, "
                            f"line {line}); expected a UTF-8 TOML file") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(source, "", f"TOML syntax error: {exc}") from None
    return parse_scenario(data, source)


def load_scenario(spec: str | os.PathLike[str]) -> Scenario:
    """Load and validate a scenario.

    Parameters
    ----------
    spec
        A built-in name (see :func:`builtin_scenario_names`) or the path of a
        TOML file. A string equal to a built-in name means the built-in; write
        e.g. ``./paper-s1`` for a file of that name.

    Raises
    ------
    ScenarioError
        Unknown name, unreadable file, or invalid content.
    """
    builtins = builtin_scenario_names()
    if isinstance(spec, str) and spec in builtins:
        raw = resources.files("sqpmpc.scenarios").joinpath(f"{spec}.toml").read_bytes()
        return _parse_text(raw, spec)
    path = Path(spec)
    source = str(spec) if isinstance(spec, str) else os.fspath(path)
    if not path.exists():
        raise ScenarioError(source, "", "neither a built-in scenario name nor an existing file; "
                            f"built-ins: {', '.join(builtins)}")
    if path.is_dir():
        raise ScenarioError(source, "", "is a directory; expected a TOML scenario file")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ScenarioError(source, "", f"cannot read: {exc.strerror or exc}") from None
    return _parse_text(raw, source)

