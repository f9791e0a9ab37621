"""Liveness with acceleration bounds on the ideal plant: symmetric encounters resolve.

With ``[bounds] acceleration`` the rows keep a margin for how far a robot that
accelerates within the bounds can stray from the predicted segments (0.5 m
between two robots at 2 m/s^2 and Ts = 0.5 s), and a robot cannot stop at once.
The liveness rules measure "near" from that kept distance (``detour``,
``roundabout``), so the symmetric swap of six robots (which stood still in a
ring to the end of the run) and the four-way crossing arrive, in both schemes,
with no collision at the samples or between them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import simulate

GOAL = 0.05


def _with_accelerations(name: str) -> object:
    sc = load_scenario(name)
    return sc.with_changes(bounds=dataclasses.replace(
        sc.bounds, acceleration=(-2.0, 2.0), angular_acceleration=(-7.1, 7.1)))


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
@pytest.mark.parametrize("name", ["swap-6", "crossing-4"])
def test_symmetric_encounters_arrive_with_acceleration_bounds(name: str, scheme: str) -> None:
    sc = _with_accelerations(name)
    rec = simulate(sc, scheme)
    m = compute_metrics(rec)
    assert m["collisions"] == 0
    assert m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0
    errors = np.linalg.norm(rec.positions - rec.references(), axis=-1)
    # every robot within tolerance at the end, and it stays there over the last 2 s
    tail = int(round(2.0 / sc.sample_time))
    assert (errors[-tail:] <= GOAL).all(), errors[-1]
    # the velocities the robots followed stay within the declared bounds
    bounds = sc.bounds
    v = rec.inputs[..., 0]
    assert (v >= bounds.v[0] - 1e-6).all() and (v <= bounds.v[1] + 1e-6).all()
    dv = np.diff(np.concatenate((np.zeros((1, sc.n_robots)), v)), axis=0) / sc.sample_time
    assert (np.abs(dv) <= bounds.acceleration[1] + 1e-6).all()


def test_corridor_decentralized_keeps_its_distances_with_acceleration_bounds() -> None:
    """Robots entering side by side inside the margin band: no collision (the braking
    check keeps the true-distance line the neighbour keeps too) and every robot arrives."""
    sc = _with_accelerations("corridor")
    rec = simulate(sc, "decentralized")
    m = compute_metrics(rec)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0
    final = [e for e in m["final_position_error"].values() if e is not None]
    assert max(final) <= GOAL
