"""The coordination plug-in in the closed loop: in one-cell mazes every robot arrives,
both schemes, with every distance and bound kept and one plan in every controller."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sqpmpc.control.settings import SolverSettings
from sqpmpc.coordination.schedule import Execution
from sqpmpc.errors import ProblemError
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.fleets import grid_to_grid
from sqpmpc.problem.movingai import mapf_scenario
from sqpmpc.problem.references import PointReference
from sqpmpc.problem.scenario import Bounds
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.rules.registry import select_rules
from sqpmpc.sim.simulation import ClosedLoopSimulation
from tests.map_helpers import turned_maze

DATA = Path(__file__).parent / "data"


def _run(scenario, scheme: str) -> tuple[dict, ClosedLoopSimulation]:
    sim = ClosedLoopSimulation(scenario, scheme, SolverSettings(
        rules=select_rules(["coordination"])))
    metrics = compute_metrics(sim.run())
    return metrics, sim


def _arrived(sim: ClosedLoopSimulation) -> np.ndarray:
    goals = sim.scenario.reference_positions(sim.scenario.t_end)
    return np.hypot(*(sim.states[-1, :, :2] - goals).T) <= 0.05


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
@pytest.mark.parametrize(("name", "robots"), [("maze-12-8", 6), ("blocks-17-9", 10)])
def test_in_a_one_cell_maze_every_robot_arrives_and_keeps_every_distance_and_bound(
        name: str, robots: int, scheme: str) -> None:
    """0.5 m corridors, 0.3 m robots with acceleration limits, crossing from both sides."""
    sc = mapf_scenario(DATA / f"{name}.map", robots, scen_path=DATA / f"{name}.scen", cell=0.5,
                       diameter=0.3, acceleration=2.0, angular_acceleration=10.0)
    m, sim = _run(sc, scheme)
    assert m["completed"]
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0 and m["input_bound_violations"] == 0
    counters = sim.counters()
    assert counters["samples"] == sc.steps * (1 if scheme == "centralized" else sc.n_robots)
    plan = sim.controllers[0].rule("coordination").plan
    assert plan is not None and plan.robots.size == robots
    for controller in sim.controllers:  # every controller has the same plan: no coordinator
        assert controller.rule("coordination").plan is plan
    assert _arrived(sim).all(), f"arrived: {_arrived(sim)}"
    _a_controller_joining_at_any_sample_counts_the_same_progress(sim)


def test_a_maze_drawn_without_its_grid_gets_its_cells_and_every_robot_arrives() -> None:
    """The test maze's walls without its ``[roadmap]`` (a maze drawn by hand), coordination
    on: the grid is read from the walls (the same cells) and every robot arrives keeping
    every distance (with the grid fitted to the robots' points instead, 0.47 m off the
    corridors' centres, LaCAM searched without end; the ten rules brought 0 of 6 home)."""
    declared = mapf_scenario(DATA / "maze-12-8.map", 6, scen_path=DATA / "maze-12-8.scen",
                             cell=0.5, diameter=0.3, acceleration=2.0,
                             angular_acceleration=10.0)
    m, sim = _run(declared.with_changes(roadmap=None), "decentralized")
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0 and m["input_bound_violations"] == 0
    assert _arrived(sim).all(), f"arrived: {_arrived(sim)}"
    plan = sim.controllers[0].rule("coordination").plan
    grid = declared.roadmap
    assert plan.roadmap.spacing == grid.cell  # the map's own cells, centred
    offset = (plan.roadmap.positions - np.asarray(grid.origin)) / grid.cell
    np.testing.assert_allclose(offset, np.round(offset), atol=1e-9)


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_in_a_maze_turned_off_the_axes_every_robot_arrives(scheme: str) -> None:
    """The test maze turned by 30 degrees (its 0.5 m corridors in no axis's direction, no
    declared grid): coordination plans on lanes along the corridors' middles and every
    robot arrives keeping every distance and bound (on the grid alone there was no plan:
    no path of grid vertices joined robot 5's start to its goal; the ten rules bring 0
    of 6 home)."""
    m, sim = _run(turned_maze("maze-12-8", 6, 30.0), scheme)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0 and m["input_bound_violations"] == 0
    assert _arrived(sim).all(), f"arrived: {_arrived(sim)}"


def _a_controller_joining_at_any_sample_counts_the_same_progress(sim) -> None:
    """A controller started (or restarted) at sample k has only that sample's positions:
    :meth:`Execution.resume` gives it the progress the running controllers counted."""
    rule = sim.controllers[0].rule("coordination")
    plan, window = rule.plan, rule.execution.window
    history = Execution(plan.schedule, plan.roadmap, plan.robots, window)
    for k, states in enumerate(sim.states):
        counted = history.advance(states[:, :2])
        joined = Execution(plan.schedule, plan.roadmap, plan.robots, window)
        assert np.array_equal(joined.resume(states[:, :2]), counted), k


@pytest.mark.parametrize(("acceleration", "scheme"), [
    (None, "decentralized"), (3.0, "decentralized"), (3.0, "centralized")])
def test_the_corridor_arrives_with_coordination(acceleration, scheme) -> None:
    """The corridor built-in (goals 0.8 m apart), also with acceleration limits of 3 m/s^2,
    where the old margin kept 0.75 m beyond the diameter: the pair rows of either scheme
    keep 2 L (sqpmpc.problem.margins), and the roadmap is laid for what they keep."""
    sc = load_scenario("corridor")
    if acceleration is not None:
        b = sc.bounds
        sc = sc.with_changes(bounds=Bounds(
            v=b.v, omega=b.omega, x=b.x, y=b.y, acceleration=(-acceleration, acceleration),
            angular_acceleration=(-10.0, 10.0)))
    m, sim = _run(sc, scheme)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0
    goals = sim.scenario.reference_positions(0.0)
    assert np.hypot(*(sim.states[-1, :, :2] - goals).T).max() <= 0.05


def test_when_progress_stops_every_robot_is_planned_again_from_where_it_stands() -> None:
    """Robots that do not move (the measurement never changes: motors off) make no
    progress: after the patience (the time a free robot needs to reach its next vertex,
    in samples) the controller plans again from the measured positions, once per
    patience, each robot from its own vertex; a robot measured on another robot's next
    vertex starts the new plan there, the other from a distinct vertex."""
    sc = mapf_scenario(DATA / "maze-12-8.map", 6, scen_path=DATA / "maze-12-8.scen", cell=0.5,
                       diameter=0.3, acceleration=2.0, angular_acceleration=10.0)
    sim = ClosedLoopSimulation(sc, "centralized", SolverSettings(
        rules=select_rules(["coordination"])))
    controller = sim.controllers[0]
    rule = controller.rule("coordination")
    first, patience = rule.plan, rule.patience
    assert 0 < patience < sc.steps // 3
    measured = sim.plant.measure(sim.states[0])
    for k in range(2 * patience + 1):
        out = controller.step(sim.t[k], measured)
        assert np.all(np.isfinite(out.inputs))
        # no progress from sample 0: a new plan at sample `patience`, the next one a
        # patience after the sample following it
        assert controller.counters()["coordination_stalls"] == int(k >= patience), k
    stalls = controller.counters()["coordination_stalls"]
    plan = rule.plan
    assert plan is not first
    assert np.array_equal(plan.configs[0], first.configs[0])  # each from its own vertex
    assert np.array_equal(plan.configs[-1], first.configs[-1])  # to the same goals
    # robot 1 pushed onto robot 0's next vertex
    nxt = first.roadmap.positions[first.schedule.paths[0, 1]]
    pushed = measured.copy()
    pushed[first.robots[1], :2] = nxt + 0.01
    for k in range(2 * patience + 1, 3 * patience + 3):
        controller.step(sim.t[k], pushed)
    assert controller.counters()["coordination_stalls"] > stalls
    starts = rule.plan.configs[0]
    assert starts[1] == first.schedule.paths[0, 1] and np.unique(starts).size == starts.size


def _grid(rows: int = 3, cols: int = 3):
    return grid_to_grid(rows, cols)


def test_a_robot_that_leaves_is_planned_standing_and_kept_apart_from() -> None:
    """A 3x3 formation crossing to its mirror, decentralized: robot 5's controller (the
    middle of the formation, which robots behind it wait for) leaves at sample 1. Every
    other controller is told at once and plans again from where the robots stand, to one
    plan, with robot 5 standing on a vertex no other path enters; robot 5 stops and stands;
    the eight others arrive; no collision of any kind, no bound violated."""
    sc = _grid()
    sim = ClosedLoopSimulation(sc, "decentralized", SolverSettings(
        rules=select_rules(["coordination"])))
    sim.step()
    sim.depart(5)
    left_at = sim.states[sim.k, sc.index_of(5), :2].copy()
    record = sim.run()
    m = compute_metrics(record)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0 and m["input_bound_violations"] == 0
    gone = sc.index_of(5)
    assert np.hypot(*(sim.states[-1, gone, :2] - left_at)) <= 0.05  # it stood
    plans = set()
    for c in sim.controllers:
        if c.robot_id == 5:
            assert c.counters()["samples"] == 1  # it computed nothing after it left
            continue
        rule = c.rule("coordination")
        assert c.counters()["coordination_departures"] == 1
        plans.add(id(rule.plan))
        plan = rule.plan
        row = int(np.flatnonzero(plan.robots == gone)[0])
        assert plan.schedule.lengths[row] == 1  # planned standing
        vertex = plan.schedule.paths[row, 0]
        assert plan.roadmap.neighbours(vertex).size == 0  # cut off the roadmap
        others = np.delete(plan.configs, row, axis=1)
        assert not (others == vertex).any()  # no other path enters it
    assert len(plans) == 1  # every controller the same plan
    # the others arrive: a robot that left is braked by its plant, so it keeps no plan-age
    # disc around it (DecentralizedController.track_plan_ages)
    goals = sc.reference_positions(0.0)
    err = np.hypot(*(sim.states[-1, :, :2] - goals).T)
    assert np.all(np.delete(err, gone) <= 0.05), np.round(err, 3)


def test_departures_are_checked_and_a_robot_back_is_planned_to_its_goal_again() -> None:
    """``update_departed``: a robot of the controller itself or an unknown id is refused by
    name; told that robot 2 left and then that it is back, the controller plans twice
    (``coordination_departures``) and the second plan sends robot 2 to its goal."""
    sc = _grid()
    sim = ClosedLoopSimulation(sc, "decentralized", SolverSettings(
        rules=select_rules(["coordination"])))
    controller = sim.controllers[0]
    with pytest.raises(ProblemError, match="robot 1 is driven by this controller"):
        controller.update_departed([1])
    with pytest.raises(ProblemError, match="update_departed"):
        controller.update_departed([99])
    sim.step()
    sim.depart(2)
    sim.step()
    rule = controller.rule("coordination")
    two = int(np.flatnonzero(rule.plan.robots == sc.index_of(2))[0])
    assert rule.plan.schedule.lengths[two] == 1
    sim.departed.clear()
    for c in sim.controllers:
        c.update_departed([])
    sim.step()
    assert controller.counters()["coordination_departures"] == 2
    goal = sc.reference_positions(0.0)[sc.index_of(2)]
    assert np.allclose(rule.plan.goals[two], goal)
    assert np.allclose(rule.plan.roadmap.positions[rule.plan.configs[-1, two]], goal)


def test_a_new_goal_is_planned_and_reached() -> None:
    """``update_reference`` on every controller at sample 4: robot 1 of a 3x3 formation is
    sent to a free point beyond the goals instead; the plan is made again from the
    robots' progress (``coordination_replans``) and every robot arrives at its goal, robot
    1 at the new one, without a collision."""
    sc = _grid()
    sim = ClosedLoopSimulation(sc, "decentralized", SolverSettings(
        rules=select_rules(["coordination"])))
    for _ in range(4):
        sim.step()
    new_goal = sc.reference_positions(0.0).max(axis=0) + np.array([1.0, 0.0])
    for c in sim.controllers:
        c.update_reference(1, PointReference(new_goal))
    record = sim.run()
    m = compute_metrics(record)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert all(c.counters()["coordination_replans"] == 1 for c in sim.controllers)
    goals = sc.reference_positions(0.0)
    goals[sc.index_of(1)] = new_goal
    assert (np.hypot(*(sim.states[-1, :, :2] - goals).T) <= 0.05).all()
