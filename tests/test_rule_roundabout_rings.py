"""Rule ``roundabout``, its fixed rings: where several straight ways cross at about the same
time (an antipodal swap), the robots pass one ring counter-clockwise from the start."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.errors import ProblemError
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.kernels.rings import ring_path, ring_zones
from sqpmpc.problem.fleets import antipodal_swap
from sqpmpc.problem.obstacles import Obstacle
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.rules.roundabout import Roundabout
from sqpmpc.sim.simulation import ClosedLoopSimulation
from tests.rule_helpers import fleet, only, shape, view

RULE = Roundabout()


def _zones(positions: np.ndarray, goals: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    n = positions.shape[0]
    zone_of = np.zeros(n, dtype=np.int64)
    centres = np.zeros((n, 2))
    travelling = np.hypot(*(goals - positions).T) > RULE.goal_distance
    count = ring_zones(positions, goals, travelling, RULE.ring_window, math.cos(RULE.along),
                       RULE.ring_cluster, RULE.ring_crowd, 0.5, zone_of, centres)
    return count, zone_of, centres[:count]


def _circle(n: int, radius: float = 3.0) -> np.ndarray:
    a = 2.0 * np.pi * np.arange(n) / n
    return radius * np.column_stack((np.cos(a), np.sin(a)))


def test_the_ways_of_a_swap_meet_in_one_ring_at_the_centre() -> None:
    starts = _circle(8) + np.random.default_rng(0).uniform(-0.01, 0.01, (8, 2))
    count, zone_of, centres = _zones(starts, -_circle(8))
    assert count == 1
    np.testing.assert_array_equal(zone_of, 0)
    assert np.hypot(*centres[0]) < 0.05


def _zones_by_counting_all(positions: np.ndarray, goals: np.ndarray
                           ) -> tuple[int, np.ndarray, np.ndarray]:
    """The greedy of ``ring_zones`` as its docstring states it, every meeting point counted
    against every other (O(m^2) per zone)."""
    n = positions.shape[0]
    travelling = np.hypot(*(goals - positions).T) > RULE.goal_distance
    d = goals - positions
    u = d / np.maximum(np.hypot(*d.T), 1e-300)[:, None]
    length = np.hypot(*d.T)
    points, pairs = [], []
    for i in range(n):
        for j in range(i + 1, n):
            if not (travelling[i] and travelling[j]) or u[i] @ u[j] > math.cos(RULE.along):
                continue
            cross = u[i, 0] * u[j, 1] - u[i, 1] * u[j, 0]
            r = positions[j] - positions[i]
            if abs(cross) < 0.05:
                if abs(r[0] * u[i, 1] - r[1] * u[i, 0]) > RULE.ring_cluster or r @ u[i] <= 0:
                    continue
                a = 0.5 * math.hypot(*r)
                if a > length[i] or a > length[j]:
                    continue
                points.append(0.5 * (positions[i] + positions[j]))
            else:
                a = (r[0] * u[j, 1] - r[1] * u[j, 0]) / cross
                b = (r[0] * u[i, 1] - r[1] * u[i, 0]) / cross
                if a <= 0 or b <= 0 or a > length[i] or b > length[j] or abs(a - b) > \
                        RULE.ring_window:
                    continue
                points.append(positions[i] + a * u[i])
            pairs.append((i, j))
    pts = np.array(points).reshape(-1, 2)
    used = np.zeros(len(pts), dtype=bool)
    zone_of = np.full(n, -1)
    centres = []
    while not used.all():
        near = (np.hypot(*(pts[:, None] - pts[None]).transpose(2, 0, 1)) <= RULE.ring_cluster)
        counts = (near & ~used[None]).sum(axis=1) * ~used
        best = int(np.argmax(counts))  # the first of the largest
        chosen = np.flatnonzero(near[best] & ~used)
        used[chosen] = True
        members = sorted({r for q in chosen for r in pairs[q] if zone_of[r] < 0})
        resultant = math.hypot(*u[members].sum(axis=0)) if members else 0.0
        if len(members) < RULE.ring_crowd or resultant > 0.5 * len(members):
            continue
        zone_of[members] = len(centres)
        centres.append(pts[chosen].mean(axis=0))
        used |= np.array([zone_of[i] >= 0 or zone_of[j] >= 0 for i, j in pairs], dtype=bool)
    return len(centres), zone_of, np.array(centres).reshape(-1, 2)


@pytest.mark.parametrize("seed", range(12))
def test_ring_zones_are_those_of_counting_every_meeting_point(seed: int) -> None:
    """The binned search finds the zones the plain greedy finds: swaps, crossings and
    streams, dense and sparse (many ties of equal counts)."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(6, 60))
    if seed % 3 == 0:  # a swap, some robots moved
        starts = _circle(n, 3.0 * math.sqrt(n / 6.0)) + rng.uniform(-0.3, 0.3, (n, 2))
        goals = -starts + rng.uniform(-0.3, 0.3, (n, 2))
    elif seed % 3 == 1:  # random crossings
        side = 6.0 * math.sqrt(n / 6.0)
        starts, goals = rng.uniform(-side / 2, side / 2, (2, n, 2))
    else:  # two swaps side by side and a stream
        k = n // 3
        stream = np.column_stack((rng.uniform(-8, 8, n - 2 * k), np.full(n - 2 * k, -6.0)))
        starts = np.vstack([_circle(k, 3.0) - [5.0, 0.0], _circle(k, 3.0) + [5.0, 0.0], stream])
        goals = np.vstack([-_circle(k, 3.0) - [5.0, 0.0], -_circle(k, 3.0) + [5.0, 0.0],
                           starts[2 * k:] + [0.0, 12.0]])
    count, zone_of, centres = _zones(starts, goals)
    want_count, want_zone_of, want_centres = _zones_by_counting_all(starts, goals)
    assert count == want_count
    np.testing.assert_array_equal(zone_of, want_zone_of)
    np.testing.assert_allclose(centres, want_centres, rtol=0, atol=1e-12)


@pytest.mark.parametrize("case", ["one head-on with a group", "formation", "three", "far apart"])
def test_no_ring_where_the_ways_do_not_meet_from_all_sides(case: str) -> None:
    if case == "one head-on with a group":  # 1 robot east, 4 west on its line: no ring
        starts = np.array([[0.0, 0.0], [2.0, 0.0], [2.3, 0.3], [2.3, -0.3], [2.6, 0.0]])
        goals = np.vstack([[8.0, 0.0], starts[1:] - [6.0, 0.0]])
    elif case == "formation":  # everyone the same way: traffic
        starts = np.array([[x, y] for x in (0.0, 1.0) for y in (0.0, 1.0, 2.0)])
        goals = starts + [5.0, 0.0]
    elif case == "three":  # fewer than ring_crowd
        starts, goals = _circle(3), -_circle(3)
    else:  # a swap whose robots reach the centre at very different times
        starts = _circle(6) * np.array([1.0, 3.0, 5.0, 7.0, 9.0, 11.0])[:, None]
        goals = -starts
    count, zone_of, _ = _zones(starts, goals)
    assert count == 0
    np.testing.assert_array_equal(zone_of, -1)


def test_the_ring_path_passes_counter_clockwise_outside_the_ring_then_leaves() -> None:
    out = np.zeros((60, 2))
    ring_path(-3.0, 0.0, 3.0, 0.0, 0.0, 0.0, 1.0, 0.3, out)
    points = np.vstack([[-3.0, 0.0], out])
    assert np.all(np.hypot(*points.T) >= 1.0 - 1e-9)  # never inside the ring
    steps = np.hypot(*np.diff(points, axis=0).T)
    moving = steps > 1e-12
    np.testing.assert_allclose(steps[moving][:-1], 0.3, atol=0.01)  # arcs: chords
    assert points[1, 1] < 0.0  # to the right of the way: the ring on the left
    a, b = points[1:-1] - points[:-2], points[2:] - points[1:-1]
    turn = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    assert np.all(turn[np.abs(turn) > 1e-9] > 0.0)  # always turning left (counter-clockwise)
    np.testing.assert_allclose(out[-1], [3.0, 0.0], atol=1e-9)  # ends at the goal


def test_a_robot_inside_the_ring_spirals_out_counter_clockwise() -> None:
    out = np.zeros((8, 2))
    ring_path(0.2, 0.0, 3.0, 3.0, 0.0, 0.0, 1.0, 0.3, out)
    radii = np.hypot(*out.T)
    assert np.all(np.diff(radii) >= -1e-12) and radii[0] > 0.2
    assert np.all(np.diff(np.unwrap(np.arctan2(out[:, 1], out[:, 0]))) >= 0.0)


def test_a_swap_robot_follows_the_ring_from_its_first_sample() -> None:
    sc = antipodal_swap(8)
    states = sc.initial_states()
    ctrl = DecentralizedController(sc, 1, only("roundabout"))
    inst = ctrl.rule("roundabout")
    v = shape(ctrl, inst, view(ctrl, states))
    assert ctrl.counters()["ring_samples"] == 1
    np.testing.assert_array_equal(inst.zone_of, 0)
    u = v.references[0, 0] - states[0, :2]
    to_goal = sc.reference_positions(0.0)[0] - states[0, :2]
    assert to_goal[0] * u[1] - to_goal[1] * u[0] < 0.0  # veers right of the straight way
    assert np.hypot(*u) == pytest.approx(0.3)


@pytest.mark.parametrize("name", ["paper-s1", "paper-s2"])
def test_references_that_never_rest_make_no_ring(name: str) -> None:
    sc = load_scenario(name)
    ctrl = DecentralizedController(sc, 1)
    inst = ctrl.rule("roundabout")
    shape(ctrl, inst, view(ctrl, sc.initial_states()))
    np.testing.assert_array_equal(inst.zone_of, -1)


def test_a_pillar_in_the_ring_drops_it() -> None:
    sc = antipodal_swap(8).with_changes(obstacles=(Obstacle(position=(5.0, 5.0),
                                                            diameter=0.6),))
    ctrl = DecentralizedController(sc, 1, only("roundabout"))
    inst = ctrl.rule("roundabout")
    shape(ctrl, inst, view(ctrl, sc.initial_states()))
    np.testing.assert_array_equal(inst.zone_of, 0)  # a pillar far from the ring
    crowded = antipodal_swap(8).with_changes(obstacles=(Obstacle(position=(0.0, 1.0),
                                                                 diameter=0.4),))
    ctrl = DecentralizedController(crowded, 1, only("roundabout"))
    inst = ctrl.rule("roundabout")
    shape(ctrl, inst, view(ctrl, crowded.initial_states()))
    np.testing.assert_array_equal(inst.zone_of, -1)


def test_a_group_head_on_is_left_to_the_crowd_rule() -> None:
    crowd = [[2.0, 0.0], [2.3, 0.3], [2.3, -0.3], [2.6, 0.0]]
    starts = [[0.0, 0.0, 0.0]] + [[x, y, np.pi] for x, y in crowd]
    sc = fleet(starts, [[8.0, 0.0]] + [[x - 6.0, y] for x, y in crowd])
    ctrl = DecentralizedController(sc, 1, only("roundabout"))
    shape(ctrl, ctrl.rule("roundabout"), view(ctrl, np.array(starts)))
    counts = ctrl.counters()
    assert counts["ring_samples"] == 0 and counts["roundabout_samples"] == 1


@pytest.mark.parametrize(("field", "value"), [("ring_crowd", 0), ("ring_crowd", 4.5),
                                              ("ring_spacing", -1.0), ("ring_window", 0.0),
                                              ("ring_cluster", float("inf"))])
def test_bad_ring_parameters_are_refused_by_name(field: str, value: float) -> None:
    with pytest.raises(ProblemError, match=f"roundabout.*{field}"):
        Roundabout(**{field: value})


def test_a_swap_of_eight_arrives_around_its_ring_without_collision() -> None:
    scenario = antipodal_swap(8)
    record = ClosedLoopSimulation(scenario, "decentralized").run()
    m = compute_metrics(record)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    goals = scenario.reference_positions(record.t[-1])
    assert np.all(np.hypot(*(record.states[-1, :, :2] - goals).T) <= 0.05)
    assert m["counters"]["ring_samples"] > 0
