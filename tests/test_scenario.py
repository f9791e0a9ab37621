"""Scenario files and references: built-ins, validation errors, maths, round trip."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.problem.references import (
    HarmonicReference,
    PointReference,
    Reference,
    WaypointReference,
    reference_from_dict,
)
from sqpmpc.problem.scenario import Bounds, RobotSpec, Scenario, Weights
from sqpmpc.problem.scenario_file import builtin_scenario_names, load_scenario, parse_scenario

BASE = """\
name = "unit"
t_end = 10.0
sample_time = 0.5
horizon = 4

[weights]
Q = [1.0, 2.0]
R = [0.5, 0.25]

[bounds]
v = [-0.6, 0.6]
omega = [-0.8, 0.8]
x = [-10.0, 10.0]
y = [-5.0, 5.0]

[[robots]]
id = 1
initial_state = [0.0, 0.0, 0.0]
diameter = 0.3
reference = { type = "harmonic", omega = 0.1, x = [0.0, 1.0, 0.5], y = [1.0, -2.0, 0.25] }

[[robots]]
id = 2
initial_state = [1.0, 0.0, 1.5]
diameter = 0.4
reference = { type = "point", position = [3.0, -1.0] }

[[robots]]
id = 7
initial_state = [-2.0, 2.0, -1.0]
diameter = 0.5
reference = { type = "waypoints", times = [1.0, 3.0, 6.0], points = [[0, 0], [2, 1], [2, -3]] }
"""

ROBOTS_AT = BASE.index("[[robots]]")


def _sub(old: str, new: str) -> str:
    """BASE with exactly one occurrence of ``old`` replaced (fails loudly if absent)."""
    if BASE.count(old) != 1:
        raise RuntimeError(f"test fixture: {old!r} occurs {BASE.count(old)} times in BASE")
    return BASE.replace(old, new)


def _write(tmp_path: Path, text: str | bytes, name: str = "case.toml") -> Path:
    path = tmp_path / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8")
    return path


H_REF = 'type = "harmonic", omega = 0.1, x = [0.0, 1.0, 0.5], y = [1.0, -2.0, 0.25]'
P_REF = 'type = "point", position = [3.0, -1.0]'
W_REF = 'type = "waypoints", times = [1.0, 3.0, 6.0], points = [[0, 0], [2, 1], [2, -3]]'

BAD_CASES: list[tuple[str, str, str]] = [
    # unknown keys, everywhere
    ("unknown top-level key", "obstacle = []\n" + BASE, "obstacle"),
    ("unknown key in [plant]", BASE + "\n[plant]\nnoise = 0.1\n", "plant.noise"),
    ("unknown plant model", BASE + '\n[plant]\nmodel = "rk5"\n', "plant.model"),
    ("negative input noise", BASE + "\n[plant]\ninput_noise = [0.1, -0.1]\n",
     "plant.input_noise"),
    ("obstacle without a diameter", BASE + "\n[[obstacles]]\nposition = [9.0, 9.0]\n",
     "obstacles[0].diameter"),
    ("obstacle with a bad velocity", BASE + "\n[[obstacles]]\nposition = [9.0, 9.0]\n"
     "diameter = 0.5\nvelocity = [1.0]\n", "obstacles[0].velocity"),
    ("obstacle on a robot at t = 0", BASE + "\n[[obstacles]]\nposition = [9.0, 9.0]\n"
     "diameter = 0.5\n\n[[obstacles]]\nposition = [1.0, 0.3]\ndiameter = 0.5\n",
     "obstacles[1].position"),
    ("unknown key in weights", _sub("R = [0.5, 0.25]", "R = [0.5, 0.25]\nS = [1.0, 1.0]"),
     "weights.S"),
    ("unknown key in bounds", _sub("y = [-5.0, 5.0]", "y = [-5.0, 5.0]\nz = [0.0, 1.0]"),
     "bounds.z"),
    ("unknown key in a robot", _sub("id = 2\n", 'id = 2\ncolour = "red"\n'), "robots[1].colour"),
    ("unknown key in a reference", _sub(P_REF, P_REF + ", speed = 1.0"),
     "robots[1].reference.speed"),
    ("key of another reference type", _sub(H_REF, H_REF + ", position = [0.0, 0.0]"),
     "robots[0].reference.position"),
    # missing required keys
    ("missing name", _sub('name = "unit"\n', ""), "name"),
    ("missing t_end", _sub("t_end = 10.0\n", ""), "t_end"),
    ("missing sample_time", _sub("sample_time = 0.5\n", ""), "sample_time"),
    ("missing horizon", _sub("horizon = 4\n", ""), "horizon"),
    ("missing weights", _sub("[weights]\nQ = [1.0, 2.0]\nR = [0.5, 0.25]\n", ""), "weights"),
    ("missing weights.Q", _sub("Q = [1.0, 2.0]\n", ""), "weights.Q"),
    ("missing weights.R", _sub("R = [0.5, 0.25]\n", ""), "weights.R"),
    ("missing bounds.v", _sub("v = [-0.6, 0.6]\n", ""), "bounds.v"),
    ("missing bounds.omega", _sub("omega = [-0.8, 0.8]\n", ""), "bounds.omega"),
    ("missing robots", BASE[:ROBOTS_AT], "robots"),
    ("missing robot id", _sub("id = 7\n", ""), "robots[2].id"),
    ("missing initial_state", _sub("initial_state = [1.0, 0.0, 1.5]\n", ""),
     "robots[1].initial_state"),
    ("missing diameter", _sub("diameter = 0.5\n", ""), "robots[2].diameter"),
    ("missing reference", _sub("reference = { " + P_REF + " }\n", ""), "robots[1].reference"),
    ("missing reference type", _sub(P_REF, "position = [3.0, -1.0]"),
     "robots[1].reference.type"),
    ("missing harmonic omega", _sub(H_REF, H_REF.replace("omega = 0.1, ", "")),
     "robots[0].reference.omega"),
    ("missing waypoint times", _sub(W_REF, W_REF.replace("times = [1.0, 3.0, 6.0], ", "")),
     "robots[2].reference.times"),
    # wrong types (bool is not a number, float is not an integer)
    ("name not a string", _sub('name = "unit"', "name = 3"), "name"),
    ("empty name", _sub('name = "unit"', 'name = ""'), "name"),
    ("t_end a string", _sub("t_end = 10.0", 't_end = "10"'), "t_end"),
    ("sample_time a bool", _sub("sample_time = 0.5", "sample_time = true"), "sample_time"),
    ("horizon a float", _sub("horizon = 4", "horizon = 4.0"), "horizon"),
    ("horizon zero", _sub("horizon = 4", "horizon = 0"), "horizon"),
    ("horizon a bool", _sub("horizon = 4", "horizon = true"), "horizon"),
    ("weights not a table", _sub("[weights]\nQ = [1.0, 2.0]\nR = [0.5, 0.25]\n", "")
     .replace("horizon = 4\n", "horizon = 4\nweights = 1.0\n"), "weights"),
    ("bool inside weights.Q", _sub("Q = [1.0, 2.0]", "Q = [1.0, true]"), "weights.Q"),
    ("weights.R a string", _sub("R = [0.5, 0.25]", 'R = "0.5"'), "weights.R"),
    ("robots not an array of tables", "robots = 5\n" + BASE[:ROBOTS_AT], "robots"),
    ("no robots", "robots = []\n" + BASE[:ROBOTS_AT], "robots"),
    ("id a float", _sub("id = 2\n", "id = 2.0\n"), "robots[1].id"),
    ("id zero", _sub("id = 2\n", "id = 0\n"), "robots[1].id"),
    ("id negative", _sub("id = 2\n", "id = -2\n"), "robots[1].id"),
    ("id a bool", _sub("id = 1\n", "id = true\n"), "robots[0].id"),
    ("diameter a bool", _sub("diameter = 0.3", "diameter = true"), "robots[0].diameter"),
    ("reference a string", _sub("{ " + P_REF + " }", '"point"'), "robots[1].reference"),
    ("unknown reference type", _sub('type = "point"', 'type = "circle"'),
     "robots[1].reference.type"),
    ("harmonic omega a bool", _sub("omega = 0.1", "omega = false"),
     "robots[0].reference.omega"),
    # wrong shapes
    ("Q of length 3", _sub("Q = [1.0, 2.0]", "Q = [1.0, 2.0, 3.0]"), "weights.Q"),
    ("R of length 1", _sub("R = [0.5, 0.25]", "R = [0.5]"), "weights.R"),
    ("bounds.v of length 3", _sub("v = [-0.6, 0.6]", "v = [-0.6, 0.0, 0.6]"), "bounds.v"),
    ("bounds.x a number", _sub("x = [-10.0, 10.0]", "x = 10.0"), "bounds.x"),
    ("initial_state of length 2", _sub("[1.0, 0.0, 1.5]", "[1.0, 0.0]"),
     "robots[1].initial_state"),
    ("harmonic x of length 2", _sub("x = [0.0, 1.0, 0.5]", "x = [0.0, 1.0]"),
     "robots[0].reference.x"),
    ("point position of length 3", _sub("position = [3.0, -1.0]", "position = [3.0, -1.0, 0.0]"),
     "robots[1].reference.position"),
    ("waypoint of length 3", _sub("[2, 1]", "[2, 1, 0]"), "robots[2].reference.points[1]"),
    ("fewer times than points", _sub("times = [1.0, 3.0, 6.0]", "times = [1.0, 3.0]"),
     "robots[2].reference.times"),
    ("times not increasing", _sub("times = [1.0, 3.0, 6.0]", "times = [1.0, 3.0, 3.0]"),
     "robots[2].reference.times"),
    ("no waypoints", _sub(W_REF, 'type = "waypoints", times = [], points = []'),
     "robots[2].reference.points"),
    # non-finite numbers
    ("t_end inf", _sub("t_end = 10.0", "t_end = inf"), "t_end"),
    ("sample_time nan", _sub("sample_time = 0.5", "sample_time = nan"), "sample_time"),
    ("nan in Q", _sub("Q = [1.0, 2.0]", "Q = [nan, 2.0]"), "weights.Q"),
    ("inf bound", _sub("v = [-0.6, 0.6]", "v = [-inf, 0.6]"), "bounds.v"),
    ("nan initial heading", _sub("[-2.0, 2.0, -1.0]", "[-2.0, 2.0, nan]"),
     "robots[2].initial_state"),
    ("infinite diameter", _sub("diameter = 0.4", "diameter = inf"), "robots[1].diameter"),
    ("infinite harmonic omega", _sub("omega = 0.1", "omega = inf"), "robots[0].reference.omega"),
    ("nan waypoint time", _sub("times = [1.0, 3.0, 6.0]", "times = [1.0, nan, 6.0]"),
     "robots[2].reference.times"),
    # non-positive values
    ("zero diameter", _sub("diameter = 0.4", "diameter = 0.0"), "robots[1].diameter"),
    ("negative diameter", _sub("diameter = 0.5", "diameter = -0.5"), "robots[2].diameter"),
    ("zero sample_time", _sub("sample_time = 0.5", "sample_time = 0"), "sample_time"),
    ("negative sample_time", _sub("sample_time = 0.5", "sample_time = -0.5"), "sample_time"),
    ("zero t_end", _sub("t_end = 10.0", "t_end = 0.0"), "t_end"),
    ("negative t_end", _sub("t_end = 10.0", "t_end = -10.0"), "t_end"),
    ("zero R entry", _sub("R = [0.5, 0.25]", "R = [0.0, 0.25]"), "weights.R"),
    ("negative Q entry", _sub("Q = [1.0, 2.0]", "Q = [-1.0, 2.0]"), "weights.Q"),
    # inconsistent values
    ("v lower above upper", _sub("v = [-0.6, 0.6]", "v = [0.6, -0.6]"), "bounds.v"),
    ("omega lower above upper", _sub("omega = [-0.8, 0.8]", "omega = [0.9, 0.8]"),
     "bounds.omega"),
    ("x lower above upper", _sub("x = [-10.0, 10.0]", "x = [10.0, -10.0]"), "bounds.x"),
    ("initial position outside y bounds", _sub("[-2.0, 2.0, -1.0]", "[-2.0, 6.0, -1.0]"),
     "robots[2].initial_state"),
    ("initial position outside x bounds", _sub("[0.0, 0.0, 0.0]", "[-10.5, 0.0, 0.0]"),
     "robots[0].initial_state"),
    ("duplicate id", _sub("id = 7\n", "id = 1\n"), "robots[2].id"),
    ("robots overlap at t = 0", _sub("[1.0, 0.0, 1.5]", "[0.2, 0.0, 1.5]"),
     "robots[1].initial_state"),
    ("t_end not a multiple of sample_time", _sub("t_end = 10.0", "t_end = 10.2"), "t_end"),
    ("t_end shorter than a sample", _sub("t_end = 10.0", "t_end = 0.2"), "t_end"),
]


def test_base_fixture_is_valid(tmp_path: Path) -> None:
    sc = load_scenario(_write(tmp_path, BASE))
    assert sc.name == "unit" and sc.n_robots == 3 and sc.steps == 20


@pytest.mark.parametrize(("description", "text", "key"), BAD_CASES,
                         ids=[c[0] for c in BAD_CASES])
def test_bad_scenario_is_refused(tmp_path: Path, description: str, text: str, key: str) -> None:
    path = _write(tmp_path, text, "bad-case.toml")
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    err = info.value
    assert err.key == key, f"{description}: {err}"
    assert err.source == str(path)
    assert str(path) in str(err) and key in str(err)
    assert "expected" in err.detail or "allowed keys" in err.detail


def test_unknown_key_message_lists_allowed_keys(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"allowed keys: id, initial_state, diameter, "
                                            r"reference"):
        load_scenario(_write(tmp_path, _sub("id = 2\n", "id = 2\nmass = 3.0\n")))
    with pytest.raises(ScenarioError, match=r"name, t_end, sample_time, horizon, weights, "
                                            r"bounds, robots, obstacles, plant"):
        load_scenario(_write(tmp_path, "obstacle = []\n" + BASE))


def test_bool_is_reported_as_boolean(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"found true \(a boolean\)"):
        load_scenario(_write(tmp_path, _sub("diameter = 0.3", "diameter = true")))


def test_overlap_message_names_both_ids_and_distance(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError) as info:
        load_scenario(_write(tmp_path, _sub("[-2.0, 2.0, -1.0]", "[0.0, 0.3, -1.0]")))
    msg = str(info.value)
    assert info.value.key == "robots[2].initial_state"
    assert "id 1" in msg and "id 7" in msg
    assert "0.3 m" in msg and "0.4 m" in msg  # distance 0.3 < (0.3 + 0.5) / 2


def test_touching_robots_are_accepted(tmp_path: Path) -> None:
    sc = load_scenario(_write(tmp_path, _sub("[1.0, 0.0, 1.5]", "[0.375, 0.0, 1.5]")))
    assert sc.required_distances()[0, 1] == pytest.approx(0.35)


def test_duplicate_id_message_names_first_use(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"found 2 already used by robots\[1\]"):
        load_scenario(_write(tmp_path, _sub("id = 7\n", "id = 2\n")))


def test_toml_syntax_error_has_line(tmp_path: Path) -> None:
    path = _write(tmp_path, _sub("horizon = 4", "horizon = "))
    with pytest.raises(ScenarioError, match=r"line 4") as info:
        load_scenario(path)
    assert str(path) in str(info.value) and "TOML" in str(info.value)


def test_not_utf8_is_refused(tmp_path: Path) -> None:
    path = _write(tmp_path, BASE.encode() + b'# caf\xe9\n')
    with pytest.raises(ScenarioError, match="UTF-8") as info:
        load_scenario(path)
    assert str(path) in str(info.value)


def test_missing_file_lists_builtins(tmp_path: Path) -> None:
    path = tmp_path / "nope.toml"
    with pytest.raises(ScenarioError, match="built-ins: ") as info:
        load_scenario(path)
    assert str(path) in str(info.value)
    assert "paper-s1" in str(info.value) and "paper-s2" in str(info.value)
    with pytest.raises(ScenarioError, match="paper-s1") as info:
        load_scenario("paper-s3")
    assert "paper-s3" in str(info.value)


def test_directory_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="directory") as info:
        load_scenario(tmp_path)
    assert str(tmp_path) in str(info.value)


# -- built-ins ---------------------------------------------------------------------------------

TABLE1_STATES = [[-2.0, 3.5, 0.0], [-2.0, -3.5, 0.0], [2.0, 3.5, math.pi], [2.0, -3.5, math.pi]]
TABLE1_REF = [((-1.0, 2.0, 0.0), (1.0, 0.0, 2.0)), ((-1.0, 2.0, 0.0), (-1.0, 0.0, -2.0)),
              ((1.0, -2.0, 0.0), (1.0, 0.0, 2.0)), ((1.0, -2.0, 0.0), (-1.0, 0.0, -2.0))]


@pytest.mark.parametrize(("name", "horizon", "ts", "steps"),
                         [("paper-s1", 5, 1.0, 400), ("paper-s2", 8, 0.5, 800)])
def test_paper_builtins(name: str, horizon: int, ts: float, steps: int) -> None:
    sc = load_scenario(name)
    assert sc.name == name and sc.source == name
    assert (sc.horizon, sc.sample_time, sc.t_end, sc.steps) == (horizon, ts, 400.0, steps)
    assert sc.weights == Weights(Q=(1.0, 1.0), R=(0.5, 0.5))
    assert sc.bounds == Bounds(v=(-0.6, 0.6), omega=(-math.pi / 4, math.pi / 4))
    np.testing.assert_array_equal(sc.ids, [1, 2, 3, 4])
    assert sc.ids.dtype == np.int64
    np.testing.assert_allclose(sc.initial_states(), TABLE1_STATES, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(sc.diameters(), [0.3] * 4)
    for robot, (x, y) in zip(sc.robots, TABLE1_REF, strict=True):
        assert robot.reference == HarmonicReference(omega=0.02, x=x, y=y)
    np.testing.assert_allclose(sc.reference_positions(0.0),
                               [[-1.0, 3.0], [-1.0, -3.0], [1.0, 3.0], [1.0, -3.0]], atol=1e-15)
    # quarter period: sin = 1, cos = 0
    np.testing.assert_allclose(sc.reference_positions(math.pi / 2 / 0.02),
                               [[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]], atol=1e-12)


def test_builtin_names_and_all_builtins_round_trip(tmp_path: Path) -> None:
    names = builtin_scenario_names()
    assert {"paper-s1", "paper-s2"} <= set(names) and names == sorted(names)
    for name in names:
        sc = load_scenario(name)
        again = load_scenario(_write(tmp_path, sc.to_toml(), f"{name}.toml"))
        assert again == sc, name


def test_file_path_and_builtin_agree(tmp_path: Path) -> None:
    from importlib import resources

    text = resources.files("sqpmpc.scenarios").joinpath("paper-s2.toml").read_text("utf-8")
    path = _write(tmp_path, text, "copy.toml")
    by_path, by_str = load_scenario(path), load_scenario(str(path))
    assert by_path == load_scenario("paper-s2") == by_str
    assert by_path.source == str(path)


# -- scenario API ------------------------------------------------------------------------------


@pytest.fixture
def base(tmp_path: Path) -> Scenario:
    return load_scenario(_write(tmp_path, BASE))


def test_derived_arrays(base: Scenario) -> None:
    np.testing.assert_array_equal(base.ids, [1, 2, 7])
    np.testing.assert_array_equal(base.pairs(), [[0, 1], [0, 2], [1, 2]])
    assert base.pairs().dtype == np.int64
    np.testing.assert_allclose(base.required_distances(),
                               [[0.0, 0.35, 0.4], [0.35, 0.0, 0.45], [0.4, 0.45, 0.0]])
    np.testing.assert_array_equal(base.initial_states()[2], [-2.0, 2.0, -1.0])
    assert base.index_of(7) == 2 and base.index_of(np.int64(2)) == 1
    with pytest.raises(ProblemError, match="3"):
        base.index_of(3)
    b = base.bounds
    np.testing.assert_array_equal(b.input_lower(), [-0.6, -0.8])
    np.testing.assert_array_equal(b.input_upper(), [0.6, 0.8])
    np.testing.assert_array_equal(b.position_lower(), [-10.0, -5.0])
    np.testing.assert_array_equal(b.position_upper(), [10.0, 5.0])
    open_bounds = Bounds(v=(0.0, 1.0), omega=(-1.0, 1.0), y=(-2.0, 2.0))
    np.testing.assert_array_equal(open_bounds.position_lower(), [-np.inf, -2.0])
    np.testing.assert_array_equal(open_bounds.position_upper(), [np.inf, 2.0])


def test_single_robot_has_no_pairs(base: Scenario) -> None:
    one = base.with_changes(robots=base.robots[:1])
    assert one.pairs().shape == (0, 2)
    np.testing.assert_array_equal(one.required_distances(), [[0.0]])


def test_reference_positions_shape_and_values(base: Scenario) -> None:
    assert base.reference_positions(1.5).shape == (3, 2)
    t = np.linspace(0.0, 8.0, 12).reshape(3, 4)
    pos, vel = base.reference_positions(t), base.reference_velocities(t)
    assert pos.shape == vel.shape == (3, 4, 3, 2)
    for i, robot in enumerate(base.robots):
        np.testing.assert_array_equal(pos[..., i, :], robot.reference.position(t))
        np.testing.assert_array_equal(vel[..., i, :], robot.reference.velocity(t))
    np.testing.assert_array_equal(pos[..., 1, :], np.broadcast_to([3.0, -1.0], (3, 4, 2)))


def test_with_changes_revalidates(base: Scenario) -> None:
    longer = base.with_changes(horizon=10)
    assert longer.horizon == 10 and base.horizon == 4 and longer.robots == base.robots
    with pytest.raises(ScenarioError) as info:
        base.with_changes(horizon=0)
    assert info.value.key == "horizon" and base.source in str(info.value)
    with pytest.raises(ScenarioError, match="sample_time") as info:
        base.with_changes(sample_time=0.3)
    assert info.value.key == "t_end"
    moved = RobotSpec(id=9, initial_state=(0.1, 0.1, 0.0), diameter=0.2,
                      reference=PointReference((0.0, 0.0)))
    with pytest.raises(ScenarioError, match="overlap"):
        base.with_changes(robots=base.robots + (moved,))


def test_steps_tolerates_rounding(base: Scenario) -> None:
    sc = base.with_changes(t_end=3.0, sample_time=0.1)  # 3.0 / 0.1 = 29.999999999999996
    assert sc.steps == 30 and isinstance(sc.steps, int)


def test_dataclasses_validate_directly() -> None:
    with pytest.raises(ValueError, match="R"):
        Weights(Q=(1.0, 1.0), R=(0.0, 1.0))
    with pytest.raises(ValueError, match="lower"):
        Bounds(v=(1.0, -1.0), omega=(-1.0, 1.0))
    with pytest.raises(ValueError, match="diameter"):
        RobotSpec(id=1, initial_state=(0.0, 0.0, 0.0), diameter=-1.0,
                  reference=PointReference((0.0, 0.0)))
    with pytest.raises(ValueError, match="reference"):
        RobotSpec(id=1, initial_state=(0.0, 0.0, 0.0), diameter=1.0,
                  reference={"type": "point", "position": [0.0, 0.0]})
    w = Weights(Q=[1, 2], R=np.array([0.5, 0.5]))
    assert w.Q == (1.0, 2.0) and isinstance(w.R, tuple) and hash(w) == hash(Weights((1, 2),
                                                                                    (0.5, 0.5)))


def test_to_toml_round_trip(base: Scenario, tmp_path: Path) -> None:
    text = base.to_toml()
    again = load_scenario(_write(tmp_path, text, "again.toml"))
    assert again == base
    assert again.to_toml() == text
    assert isinstance(again.robots[2].reference, WaypointReference)
    assert again.robots[2].reference.points == ((0.0, 0.0), (2.0, 1.0), (2.0, -3.0))
    assert again.bounds.y == (-5.0, 5.0)
    awkward = base.with_changes(name='quote " name', sample_time=0.1, t_end=3.0,
                                bounds=Bounds(v=(-1e-5, 1e16), omega=(-0.7, 0.7)))
    back = load_scenario(_write(tmp_path, awkward.to_toml(), "awkward.toml"))
    assert back == awkward and back.bounds.x is None


def test_parse_scenario_from_dict(base: Scenario) -> None:
    data = tomllib.loads(BASE)
    assert parse_scenario(data, "dict") == base
    data["robots"][0]["diameter"] = -1.0
    with pytest.raises(ScenarioError, match=r"^dict: robots\[0\]\.diameter: "):
        parse_scenario(data, "dict")


def test_equality_ignores_source(base: Scenario) -> None:
    assert base.with_changes(source="elsewhere") == base


# -- references --------------------------------------------------------------------------------

REFERENCES: list[Reference] = [
    HarmonicReference(omega=0.3, x=(1.0, 2.0, -0.5), y=(-1.0, 0.25, 3.0)),
    HarmonicReference(omega=-1.7, x=(0.0, 0.0, 1.0), y=(2.0, 1.0, 0.0)),
    PointReference((1.5, -2.5)),
    WaypointReference(times=(0.0, 2.0, 5.0, 5.5), points=((0, 0), (2, 4), (-1, 1), (3, 3))),
]


@pytest.mark.parametrize("ref", REFERENCES, ids=lambda r: type(r).__name__)
def test_velocity_matches_central_differences(ref: Reference) -> None:
    rng = np.random.default_rng(7)
    t = rng.uniform(-2.0, 8.0, size=(4, 25))
    if isinstance(ref, WaypointReference):  # keep away from the kinks
        t = t[np.min(np.abs(t[..., None] - np.asarray(ref.times)), axis=-1) > 1e-3]
    h = 1e-6
    fd = (ref.position(t + h) - ref.position(t - h)) / (2 * h)
    vel = ref.velocity(t)
    assert vel.shape == np.shape(t) + (2,)
    np.testing.assert_allclose(vel, fd, atol=1e-6)
    assert np.any(vel != 0.0) or isinstance(ref, PointReference)


@pytest.mark.parametrize("ref", REFERENCES, ids=lambda r: type(r).__name__)
def test_reference_shapes_and_dict_round_trip(ref: Reference) -> None:
    assert ref.position(1.0).shape == (2,) and ref.velocity(1.0).shape == (2,)
    assert ref.position(np.zeros((2, 3, 4))).shape == (2, 3, 4, 2)
    assert ref.velocity(np.zeros((0,))).shape == (0, 2)
    assert reference_from_dict(ref.to_dict(), "mem", "r") == ref


def test_harmonic_values() -> None:
    ref = HarmonicReference(omega=0.5, x=(1.0, 2.0, 3.0), y=(-1.0, -2.0, 0.5))
    t = 1.3
    s, c = math.sin(0.5 * t), math.cos(0.5 * t)
    np.testing.assert_allclose(ref.position(t), [1 + 2 * s + 3 * c, -1 - 2 * s + 0.5 * c])
    np.testing.assert_allclose(ref.velocity(t), [0.5 * (2 * c - 3 * s), 0.5 * (-2 * c - 0.5 * s)])


def test_waypoints_hold_and_breakpoints() -> None:
    ref = WaypointReference(times=(1.0, 3.0, 6.0), points=((0.0, 0.0), (2.0, 1.0), (2.0, -3.0)))
    t = np.array([-5.0, 0.0, 1.0, 2.0, 3.0, 4.5, 6.0, 7.0, 100.0])
    np.testing.assert_allclose(ref.position(t), [[0, 0], [0, 0], [0, 0], [1, 0.5], [2, 1],
                                                 [2, -1], [2, -3], [2, -3], [2, -3]])
    np.testing.assert_allclose(ref.velocity(t), [[0, 0], [0, 0], [1, 0.5], [1, 0.5], [0, -4 / 3],
                                                 [0, -4 / 3], [0, 0], [0, 0], [0, 0]])
    single = WaypointReference(times=(2.0,), points=((4.0, -1.0),))
    np.testing.assert_array_equal(single.position([0.0, 2.0, 9.0]), [[4, -1]] * 3)
    np.testing.assert_array_equal(single.velocity([0.0, 2.0, 9.0]), np.zeros((3, 2)))


@pytest.mark.parametrize(("times", "points", "match"), [
    ((), (), "point"),
    ((0.0, 1.0), ((0.0, 0.0),), "one time per point"),
    ((1.0, 0.5), ((0.0, 0.0), (1.0, 1.0)), "strictly increasing"),
    ((0.0, math.inf), ((0.0, 0.0), (1.0, 1.0)), "finite"),
    ((0.0, 1.0), ((0.0, 0.0), (1.0,)), r"points\[1\]"),
])
def test_waypoint_validation(times: tuple, points: tuple, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        WaypointReference(times=times, points=points)


def test_reference_from_dict_errors() -> None:
    with pytest.raises(ScenarioError, match=r"^f\.toml: r\.type: .*'harmonic'"):
        reference_from_dict({"type": 3}, "f.toml", "r")
    with pytest.raises(ScenarioError, match=r"r\.omega: missing"):
        reference_from_dict({"type": "harmonic", "x": [0, 0, 0], "y": [0, 0, 0]}, "f", "r")
    with pytest.raises(ScenarioError, match=r"r\.x: expected an array of 3"):
        reference_from_dict({"type": "harmonic", "omega": 1, "x": [0, 0], "y": [0, 0, 0]},
                            "f", "r")
    with pytest.raises(ScenarioError, match=r"r: expected an inline table"):
        reference_from_dict([1, 2], "f", "r")


def test_float_horizon_message_says_float(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"horizon: expected an integer >= 1, found 4\.0 "
                                            r"\(a float\)"):
        load_scenario(_write(tmp_path, _sub("horizon = 4", "horizon = 4.0")))


def test_outside_bounds_message(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"inside bounds\.x = \[-10\.0, 10\.0\] and "
                                            r"bounds\.y = \[-5\.0, 5\.0\], found \(-2\.0, 6\.0\)"):
        load_scenario(_write(tmp_path, _sub("[-2.0, 2.0, -1.0]", "[-2.0, 6.0, -1.0]")))
