"""Never frozen: a robot pushed into another (or into an obstacle) mid-run, in the library's
own loop, leads both schemes to separate the robots and then go on (``overlap-recovery``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sqpmpc.control.settings import SolverSettings
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.kernels import collision as ck
from sqpmpc.problem.obstacles import Obstacle
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import ClosedLoopSimulation

GOAL = 0.05


def _push_run(scheme: str, scenario_name: str, depth: float, accelerations: bool = False
              ) -> tuple[ClosedLoopSimulation, int]:
    """Run until robots 0 and 1 are within 1 m, push robot 0 to ``depth`` inside robot 1's
    distance (its measured state), run to the end; returns the loop and the push sample.
    ``accelerations``: the robots declare acceleration bounds (CONTRACT 1c)."""
    sc = load_scenario(scenario_name)
    if accelerations:
        sc = sc.with_changes(bounds=dataclasses.replace(
            sc.bounds, acceleration=(-2.0, 2.0), angular_acceleration=(-7.0, 7.0)))
    sim = ClosedLoopSimulation(sc, scheme, SolverSettings())
    d = sc.required_distances()[0, 1]
    while np.linalg.norm(sim.states[sim.k, 0, :2] - sim.states[sim.k, 1, :2]) > 1.0:
        sim.step()
    k = sim.k
    x = sim.states[k]
    away = x[0, :2] - x[1, :2]
    x[0, :2] = x[1, :2] + (d - depth) * away / np.linalg.norm(away)
    sim.run()
    return sim, k


FROZEN_IN_BAND = pytest.mark.xfail(
    strict=True, reason="robots with acceleration limits at rest just outside their distance: "
    "the centralized check's linear path-deviation growth (|a| Ts^2 / 2 per robot) refuses "
    "every input that does not separate the pair by that much in one sample, so the zero "
    "shifted plan is applied for ever")


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
@pytest.mark.parametrize("scenario_name", ["head-on", "swap-6"])
@pytest.mark.parametrize("accelerations", [False, True], ids=["paper-robot", "accelerations"])
def test_a_pushed_pair_separates_and_every_robot_arrives(scheme: str, scenario_name: str,
                                                         accelerations: bool,
                                                         request: pytest.FixtureRequest
                                                         ) -> None:
    if accelerations and scheme == "centralized" and scenario_name == "head-on":
        request.applymarker(FROZEN_IN_BAND)
    sim, k = _push_run(scheme, scenario_name, depth=0.1, accelerations=accelerations)
    rec = sim.record()
    sc = sim.scenario
    d = sc.required_distances()
    pairs = sc.pairs().reshape(-1, 2)
    dist = np.linalg.norm(rec.states[:, pairs[:, 0], :2] - rec.states[:, pairs[:, 1], :2],
                          axis=-1) - d[pairs[:, 0], pairs[:, 1]]
    pushed = dist[k:, np.flatnonzero((pairs[:, 0] == 0) & (pairs[:, 1] == 1))[0]]
    assert pushed[0] == pytest.approx(-0.1)
    # the pushed pair never comes closer than the push left it, and separates
    assert pushed.min() >= pushed[0] - sim.settings.collision_margin
    apart = np.flatnonzero(pushed >= -1e-9)
    assert apart.size, "the pushed pair never separated"
    first = k + int(apart[0])
    # once apart, no pair overlaps again, and no other pair overlapped at all
    assert dist[first:].min() >= -1e-6
    others = np.delete(dist[:first], np.flatnonzero((pairs[:, 0] == 0) & (pairs[:, 1] == 1)),
                       axis=1)
    assert others.min(initial=np.inf) >= -1e-6
    # never frozen: not braking for the rest of the run, every robot arrives
    counters = sim.counters()
    assert counters["brake_fallbacks"] < sc.steps - k
    m = compute_metrics(rec)
    assert m["max_final_position_error"] <= GOAL, m["final_position_error"]


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_a_robot_pushed_into_an_obstacle_gets_out_and_arrives(scheme: str) -> None:
    sc = load_scenario("head-on")
    robot = sc.robots[0]
    obstacle = Obstacle((0.0, 0.6), 0.4)
    sc = sc.with_changes(robots=(robot,), obstacles=(obstacle,), t_end=30.0)
    sim = ClosedLoopSimulation(sc, scheme, SolverSettings())
    for _ in range(6):
        sim.step()
    keep = 0.5 * (robot.diameter + obstacle.diameter)
    sim.states[sim.k, 0, :2] = (0.0, 0.6 - keep + 0.08)  # 8 cm inside
    k = sim.k
    rec = sim.run()
    gap = np.linalg.norm(rec.states[k:, 0, :2] - np.array([0.0, 0.6]), axis=-1) - keep
    assert gap.min() >= gap[0] - sim.settings.collision_margin
    assert (gap >= -1e-9).any()
    assert compute_metrics(rec)["max_final_position_error"] <= GOAL


def test_recovery_kernel_accepts_only_inputs_that_do_not_approach() -> None:
    pairs = np.array([[0, 1]], dtype=np.int64)
    now = np.array([[0.0, 0.0], [0.2, 0.0]])  # 0.2 apart, 0.3 required: inside
    required, growth = np.array([0.3]), np.zeros(2)
    apart = np.array([[-0.1, 0.0], [0.3, 0.0]])
    closer = np.array([[0.05, 0.0], [0.2, 0.0]])
    for nxt, ok in ((now, True), (apart, True), (closer, False)):
        assert ck.pairs_keep_distance(pairs, now, nxt, required, growth, 1e-3) is ok
        # without the rule a pair inside its distance fails every input
        assert not ck.pairs_keep_distance(pairs, now, nxt, required, growth)
    # pairs that are apart are checked exactly as without the rule
    far = now * 2.0
    cross = np.array([[0.4, 0.0], [0.0, 0.0]])
    assert not ck.pairs_keep_distance(pairs, far, cross, required, growth, 1e-3)
    start, end = np.array([[0.2, 0.0]]), np.array([[0.2, 0.0]])
    assert ck.moving_points_keep_distance(0.0, 0.0, -0.1, 0.0, start, end, required, 0.0, 1e-3)
    assert not ck.moving_points_keep_distance(0.0, 0.0, 0.05, 0.0, start, end, required, 0.0,
                                              1e-3)
