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
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.models.base import RobotModel
from sqpmpc.problem.bounds import Bounds
from sqpmpc.problem.grid import GridSpec
from sqpmpc.problem.obstacles import Obstacle
from sqpmpc.problem.plant import PlantSpec
from sqpmpc.problem.polygons import PolygonObstacle
from sqpmpc.problem.references import (
    Reference,
    _describe,
    _FieldError,
    _integer,
    _real,
    _real_vector,
)

__all__ = [
    "MAX_HORIZON", "MAX_ROBOTS", "MAX_ROBOT_SAMPLES", "MAX_STEPS", "MIN_SAMPLE_TIME", "Bounds",
    "RobotSpec", "Scenario", "Weights",
]

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
    polygons
        Static polygon obstacles (walls, shelves: the file's ``[[obstacles]]``
        with ``points``), none overlapping a robot at :math:`t = 0`.
    roadmap
        The grid the map was drawn on (the file's ``[roadmap]``), or ``None``: the
        coordination layer then lays its own (:mod:`sqpmpc.coordination.roadmap`).

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
    polygons: tuple[PolygonObstacle, ...] = ()
    roadmap: GridSpec | None = None

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
        self._check_response()
        if not isinstance(self.polygons, list | tuple):
            raise ScenarioError(self.source, "polygons", "expected polygon obstacles, found "
                                f"{_describe(self.polygons)}")
        object.__setattr__(self, "polygons", tuple(self.polygons))
        for i, polygon in enumerate(self.polygons):
            if not isinstance(polygon, PolygonObstacle):
                raise ScenarioError(self.source, f"polygons[{i}]",
                                    f"expected a PolygonObstacle, found {_describe(polygon)}")
        self._check_obstacles()
        if self.roadmap is not None and not isinstance(self.roadmap, GridSpec):
            raise ScenarioError(self.source, "roadmap", "expected a GridSpec ([roadmap] table), "
                                f"found {_describe(self.roadmap)}")

    def _check_response(self) -> None:
        """A plant that lags (``[plant] response``): the paper's robot, whose speed settles
        within a sample from any command to any other (the checks take the command of the
        sample before as the speed a sample starts with)."""
        if self.plant.response is None:
            return
        if self.bounds.dynamic_limits:
            raise ScenarioError(self.source, "plant.response", "for the paper's robot only: "
                                "robots with acceleration bounds ramp their velocities "
                                "(CONTRACT 1c)")
        lo, hi = self.bounds.input_lower()[0], self.bounds.input_upper()[0]
        settle = self.plant.settling_time(hi - lo)
        if settle > self.sample_time:
            raise ScenarioError(self.source, "plant.response",
                                f"the speed settles in up to {settle:.3g} s (delay + "
                                f"(v_max - v_min) / acceleration), longer than the sample time "
                                f"{self.sample_time:g} s: declare acceleration bounds instead")

    def _check_obstacles(self) -> None:
        xy = self.initial_states()[:, :2]
        radius = 0.5 * self.diameters()
        for p, polygon in enumerate(self.polygons):
            gap = polygon.signed_distance(xy)
            bad = np.flatnonzero(gap < radius)
            if bad.size:
                j = int(bad[0])
                where = "inside it" if gap[j] < 0 else f"{gap[j]:.6g} m from its boundary"
                raise ScenarioError(
                    self.source, f"polygons[{p}].points",
                    f"polygon obstacle overlaps robot id {self.robots[j].id} (robots[{j}]) at "
                    f"t = 0: its centre is {where}, expected at least its radius "
                    f"{radius[j]:.6g} m outside")
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

    def robot_model(self) -> RobotModel:
        """The robots' model (:meth:`Bounds.robot_model`); the footprint is a disc of each
        robot's ``diameter``."""
        return self.bounds.robot_model()

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

    @property
    def obstacle_slots(self) -> int:
        """Obstacle rows per robot and stage: one per circle and per convex polygon piece."""
        return len(self.obstacles) + sum(len(p.pieces) for p in self.polygons)

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
        for key in ("v", "omega", "x", "y", "acceleration", "angular_acceleration"):
            value = getattr(self.bounds, key)
            if value is not None:
                lines.append(f"{key} = {_toml_value(value)}")
        for robot in self.robots:
            lines += ["", "[[robots]]", f"id = {robot.id}",
                      f"initial_state = {_toml_value(robot.initial_state)}",
                      f"diameter = {_toml_value(robot.diameter)}",
                      f"reference = {_toml_value(robot.reference.to_dict())}"]
        for obstacle in (*self.obstacles, *self.polygons):
            lines += ["", "[[obstacles]]"]
            lines += [f"{k} = {_toml_value(v)}" for k, v in obstacle.to_dict().items()]
        if self.roadmap is not None:
            lines += ["", "[roadmap]"]
            lines += [f"{k} = {_toml_value(v)}" for k, v in self.roadmap.to_dict().items()]
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


# -- loading --------------------------------------------------------------------------------


