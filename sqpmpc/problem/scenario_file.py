"""Reading scenarios: the TOML scenario file (CONTRACT section 1), its validation and the
built-in scenarios shipped in :mod:`sqpmpc.scenarios`.
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.problem.grid import ROADMAP_KEYS, GridSpec
from sqpmpc.problem.obstacles import Obstacle
from sqpmpc.problem.plant import PlantSpec
from sqpmpc.problem.polygons import PolygonObstacle
from sqpmpc.problem.references import _describe, _FieldError, reference_from_dict
from sqpmpc.problem.scenario import (
    Bounds,
    RobotSpec,
    Scenario,
    Weights,
    _check_name,
    _check_robot_count,
    _check_timing,
)

__all__ = [
    "OBSTACLE_KEYS", "OPTIONAL_TOP_KEYS", "PLANT_KEYS", "ROBOT_KEYS", "TOP_KEYS",
    "builtin_scenario_names", "load_scenario", "parse_scenario", "parse_scenario_text",
]


TOP_KEYS = ("name", "t_end", "sample_time", "horizon", "weights", "bounds", "robots")
"""The keys every scenario file has at its top level."""


OPTIONAL_TOP_KEYS = ("obstacles", "plant", "roadmap")
"""The top-level keys a scenario file may have."""


OBSTACLE_KEYS = ("position", "diameter", "velocity")
"""The keys of an ``[[obstacles]]`` entry."""


_OBSTACLE_REQUIRED = ("position", "diameter")


POLYGON_KEYS = ("points",)
"""The keys of an ``[[obstacles]]`` table of a polygon (CONTRACT 1d)."""


PLANT_KEYS = ("model", "input_noise", "seed", "response")
"""The keys of the ``[plant]`` table."""


_WEIGHT_KEYS = ("Q", "R")


_BOUND_KEYS = ("v", "omega", "x", "y", "acceleration", "angular_acceleration")


_BOUND_REQUIRED = ("v", "omega")


ROBOT_KEYS = ("id", "initial_state", "diameter", "reference")
"""The keys of a ``[[robots]]`` entry."""


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
    _table(data, source, "", TOP_KEYS + OPTIONAL_TOP_KEYS, TOP_KEYS)
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
            r = _table(raw, source, key, ROBOT_KEYS, ROBOT_KEYS)
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
    polygons = []
    polygon_keys = []  # the file's key of each polygon, for the scenario's own checks
    for i, raw in enumerate(raw_obstacles):
        key = f"obstacles[{i}]"
        if isinstance(raw, Mapping) and "points" in raw:  # a polygon (CONTRACT 1d)
            o = _table(raw, source, key, POLYGON_KEYS, POLYGON_KEYS)
            polygons.append(_build_checked(PolygonObstacle, source, key, **o))
            polygon_keys.append(key)
            continue
        o = _table(raw, source, key, OBSTACLE_KEYS, _OBSTACLE_REQUIRED)
        obstacles.append(_build_checked(Obstacle, source, key, **o))
    plant = PlantSpec()
    if "plant" in data:
        plant = _build_checked(PlantSpec, source, "plant",
                               **_table(data["plant"], source, "plant", PLANT_KEYS, ()))
    roadmap = None
    if "roadmap" in data:
        roadmap = _build_checked(GridSpec, source, "roadmap",
                                 **_table(data["roadmap"], source, "roadmap", ROADMAP_KEYS,
                                          ("cell",)))
    try:
        return Scenario(name=data["name"], t_end=data["t_end"],
                        sample_time=data["sample_time"], horizon=data["horizon"],
                        weights=weights, bounds=bounds, robots=tuple(robots),
                        obstacles=tuple(obstacles), plant=plant, source=source,
                        polygons=tuple(polygons), roadmap=roadmap)
    except ScenarioError as exc:
        if not exc.key.startswith("polygons["):
            raise
        index, _, rest = exc.key[len("polygons["):].partition("]")
        raise ScenarioError(source, polygon_keys[int(index)] + rest, exc.detail) from None


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


def builtin_scenario_names() -> list[str]:
    """Names of the built-in scenarios (stems of ``sqpmpc/scenarios/*.toml``), sorted."""
    folder = resources.files("sqpmpc.scenarios")
    return sorted(p.name[:-5] for p in folder.iterdir()
                  if p.name.endswith(".toml") and p.is_file())


def parse_scenario_text(raw: bytes, source: str) -> Scenario:
    """The scenario of a TOML file's bytes ``raw`` (``source`` names it in errors).

    Raises
    ------
    ScenarioError
        Not UTF-8, not TOML, or not a valid scenario; the message names the place.
    """
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
        return parse_scenario_text(raw, spec)
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
    return parse_scenario_text(raw, source)
