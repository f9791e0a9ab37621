"""The rule registry: names, selection, requirements, and the engine without each rule."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.fleets import antipodal_swap, grid_to_grid
from sqpmpc.problem.grid import GridSpec
from sqpmpc.problem.obstacles import Obstacle
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.rules.base import Rule
from sqpmpc.rules.registry import (
    OPT_IN,
    RULES,
    SAFETY_ROWS,
    default_names,
    describe_rules,
    roadmap_is_exact,
    rule_names,
    select_rules,
    set_rule_parameters,
)
from sqpmpc.rules.roundabout import Roundabout, crowd_without_room, find_rings, ring_min_radius
from sqpmpc.sim.simulation import simulate


@dataclass(frozen=True)
class NeedsDetour(Rule):
    """A test-local rule that requires another."""

    name = "needs-detour"
    summary = "test only"
    requires = ("detour",)


def test_describe_lists_every_rule_and_safety_row_once() -> None:
    lines = describe_rules().splitlines()
    for name in [*RULES, *SAFETY_ROWS]:
        assert sum(line.split()[0] == name for line in lines if line.startswith("  ")) == 1


def _moved(sc: object, robot: int, dx: float) -> object:
    r = sc.robots[robot]
    x, y, psi = r.initial_state
    moved = type(r)(id=r.id, initial_state=(x + dx, y, psi), diameter=r.diameter,
                    reference=r.reference)
    return sc.with_changes(robots=sc.robots[:robot] + (moved,) + sc.robots[robot + 1:])


def test_coordination_is_the_default_where_the_roadmap_is_exact() -> None:
    grid = grid_to_grid(3, 4)  # starts and goals 1 m apart on one lattice
    assert roadmap_is_exact(grid) and default_names(grid) == ["coordination"]
    # within the fitted grid's reach of its vertex: still on it; beyond: the rules
    assert roadmap_is_exact(_moved(grid, 5, 0.01))
    assert not roadmap_is_exact(_moved(grid, 5, 0.2))
    assert default_names(_moved(grid, 5, 0.2)) == default_names()
    swap = antipodal_swap(8)  # a circle: no grid holds its points
    assert not roadmap_is_exact(swap) and "coordination" not in default_names(swap)
    # a declared grid, whatever the points; timed references are not planned
    assert roadmap_is_exact(swap.with_changes(roadmap=GridSpec(0.5, (0.0, 0.0))))
    assert not roadmap_is_exact(load_scenario("paper-s2"))
    # one robot (any two points lie on some grid), or an obstacle that moves: the rules
    assert not roadmap_is_exact(grid.with_changes(robots=grid.robots[:1]))
    moving = Obstacle(position=(0.0, 5.0), diameter=0.4, velocity=(0.0, -0.1))
    assert not roadmap_is_exact(grid.with_changes(obstacles=(moving,)))
    assert roadmap_is_exact(grid.with_changes(obstacles=(Obstacle(position=(0.0, 5.0),
                                                                  diameter=0.4),)))


def test_coordination_is_the_default_where_a_crowd_has_no_room_for_its_ring() -> None:
    """A swap's ring needs members x ring_spacing of circumference; from about 115 robots
    on the swap's circle it has less (the ring is cut to its members' starts): the rules
    have no motion that passes the crowd, and coordination is on."""
    rule = Roundabout()
    for n, crowded in ((64, False), (110, False), (120, True), (256, True)):
        swap = antipodal_swap(n)
        kept = float(swap.required_distances().max())
        rings = find_rings(rule, swap.initial_states()[:, :2], swap.reference_positions(0.0),
                           kept, ring_min_radius(rule, swap, kept), swap)
        assert rings.centres.shape[0] == 1 and np.all(rings.zone_of == 0)
        assert bool(rings.radii[0] < rings.wanted[0]) is crowded
        assert crowd_without_room(swap) is crowded
        assert (default_names(swap) == ["coordination"]) is crowded
    # wider spacing asked of the ring: a smaller crowd has no room already
    assert crowd_without_room(antipodal_swap(64), Roundabout(ring_spacing=1.5))
    # timed references are not planned: the rules, crowded or not
    big = antipodal_swap(256)
    timed = big.with_changes(robots=tuple(
        type(r)(id=r.id, initial_state=r.initial_state, diameter=r.diameter,
                reference=load_scenario("paper-s2").robots[0].reference) for r in big.robots))
    assert not crowd_without_room(timed) and default_names(timed) == default_names()


def test_selection() -> None:
    assert [r.name for r in select_rules(None)] == default_names()
    assert default_names() == [n for n in rule_names() if n not in OPT_IN]
    assert select_rules(["none"]) == ()
    assert [r.name for r in select_rules(["detour", "keep-right"])] == ["keep-right", "detour"]
    assert "detour" not in [r.name for r in select_rules(None, without=["detour"])]


@pytest.mark.parametrize(("names", "without", "needle"), [
    (["nope"], [], "--rules: unknown rule 'nope'"),
    (None, ["nope"], "--without: unknown rule 'nope'"),
    (["detour", "detour"], [], "listed twice"),
])
def test_bad_selections_are_refused_by_name(names: list[str] | None, without: list[str],
                                            needle: str) -> None:
    with pytest.raises(ProblemError, match=needle):
        select_rules(names, without)


def test_a_rule_needing_another_is_refused_without_it() -> None:
    with pytest.raises(ProblemError, match="'needs-detour' requires 'detour'"):
        SolverSettings(rules=(NeedsDetour(),))
    settings = SolverSettings(rules=(NeedsDetour(), *select_rules(["detour"])))
    assert settings.rule("needs-detour") is not None
    with pytest.raises(ProblemError, match="requires 'detour'"):
        settings.without("detour")


def test_rule_parameters_by_assignment() -> None:
    rules = set_rule_parameters(select_rules(None), ["keep-right.angle=0.1", "detour.hold=3"])
    by_name = {r.name: r for r in rules}
    assert by_name["keep-right"].angle == 0.1 and by_name["detour"].hold == 3
    for bad, needle in [("keep-right.angle", "RULE.FIELD=VALUE"),
                        ("keep-right.nope=1", "no parameter 'nope'"),
                        ("keep-right.angle=x", "must be a float"),
                        ("keep-right.angle=-1", "angle must be finite and > 0")]:
        with pytest.raises(ProblemError, match=needle):
            set_rule_parameters(select_rules(None), [bad])


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
@pytest.mark.parametrize("removed", [*default_names(), "all"])
def test_engine_runs_safely_without_each_rule(removed: str, scheme: str) -> None:
    settings = SolverSettings(rules=()) if removed == "all" else SolverSettings().without(
        removed)
    for name in ("head-on", "crossing-4"):
        sc = load_scenario(name).with_changes(t_end=12.0)
        m = compute_metrics(simulate(sc, scheme, settings))
        assert m["completed"]
        assert m["collisions"] == 0 and m["intersample_collisions"] == 0
        assert m["input_bound_violations"] == 0
        assert np.isfinite(m["closed_loop_cost"])
        if removed in ("detour", "all"):  # a removed rule counts nothing
            assert "detour_activations" not in m["counters"]
