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
              ) -> tuple[ClosedLoopSimulation, int, int, int]:
    """Push a robot into another and run to the end; returns the loop, the push sample and
    the pair ``(i, j)``, ``i`` the pushed robot.

    A first run finds where two robots meet: the first sample at which a pair is within
    1 m, or the pair's closest approach if none ever is (a roundabout's ring keeps a swap's
    robots further apart). The second run pushes ``i`` there to ``depth`` inside ``j``'s
    distance (its measured state). ``accelerations``: the robots declare acceleration
    bounds (CONTRACT 1c)."""
    sc = load_scenario(scenario_name)
    if accelerations:
        sc = sc.with_changes(bounds=dataclasses.replace(
            sc.bounds, acceleration=(-2.0, 2.0), angular_acceleration=(-7.0, 7.0)))
    d = sc.required_distances()
    pairs = sc.pairs().reshape(-1, 2)
    free = ClosedLoopSimulation(sc, scheme, SolverSettings()).run().states[:, :, :2]
    gaps = np.linalg.norm(free[:, pairs[:, 0]] - free[:, pairs[:, 1]], axis=-1).min(axis=1)
    near = np.flatnonzero(gaps <= 1.0)
    k = int(near[0]) if near.size else int(np.argmin(gaps))
    sim = ClosedLoopSimulation(sc, scheme, SolverSettings())
    while sim.k < k:
        sim.step()
    x = sim.states[k]
    gap = np.linalg.norm(x[pairs[:, 0], :2] - x[pairs[:, 1], :2], axis=-1)
    i, j = (int(v) for v in pairs[int(np.argmin(gap))])
    away = x[i, :2] - x[j, :2]
    x[i, :2] = x[j, :2] + (d[i, j] - depth) * away / np.linalg.norm(away)
    sim.run()
    return sim, k, i, j


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
@pytest.mark.parametrize("scenario_name", ["head-on", "swap-6"])
@pytest.mark.parametrize("accelerations", [False, True], ids=["paper-robot", "accelerations"])
def test_a_pushed_pair_separates_and_every_robot_arrives(scheme: str, scenario_name: str,
                                                         accelerations: bool) -> None:
    sim, k, i, j = _push_run(scheme, scenario_name, depth=0.1, accelerations=accelerations)
    rec = sim.record()
    sc = sim.scenario
    d = sc.required_distances()
    pairs = sc.pairs().reshape(-1, 2)
    dist = np.linalg.norm(rec.states[:, pairs[:, 0], :2] - rec.states[:, pairs[:, 1], :2],
                          axis=-1) - d[pairs[:, 0], pairs[:, 1]]
    column = np.flatnonzero((pairs[:, 0] == min(i, j)) & (pairs[:, 1] == max(i, j)))[0]
    pushed = dist[k:, column]
    assert pushed[0] == pytest.approx(-0.1)
    # the pushed pair never comes closer than the push left it (robots with acceleration
    # limits: less what they cover while braking from the speeds they had, v^2 / (2 |a|)
    # each, as they cannot stop at once; a speed is at most the mean speed of the sample
    # before the push plus |a| Ts / 2), and separates
    coast = 0.0
    if accelerations:
        speeds = np.linalg.norm(rec.states[k - 1, [i, j], :2] - rec.states[k - 2, [i, j], :2],
                                axis=-1) / sc.sample_time + 2.0 * sc.sample_time / 2.0
        coast = float((speeds ** 2).sum() / (2.0 * 2.0))
    assert pushed.min() >= pushed[0] - sim.settings.collision_margin - coast
    apart = np.flatnonzero(pushed >= -1e-9)
    assert apart.size, "the pushed pair never separated"
    first = k + int(apart[0])
    # once apart, no pair overlaps again, and no other pair overlapped at all
    assert dist[first:].min() >= -1e-6
    others = np.delete(dist[:first], column, axis=1)
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
