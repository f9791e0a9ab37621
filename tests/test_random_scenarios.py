"""Random fleets, timings and references (benchmarks.random_scenarios): every run is safe."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.random_scenarios import random_scenario, run_random, safety_violations


def test_random_scenarios_are_valid_and_reproducible() -> None:
    a, b = random_scenario(7), random_scenario(7)
    assert a == b and a != random_scenario(8)
    x0 = a.initial_states()
    d = a.required_distances()
    gaps = np.hypot(*(x0[:, None, :2] - x0[None, :, :2]).transpose(2, 0, 1))
    off = ~np.eye(a.n_robots, dtype=bool)
    assert np.all(gaps[off] > d[off])


# seeds covering 2-6 robots, Ts 0.1-1.0 s, point and waypoint references, message loss
@pytest.mark.parametrize("seed", [0, 3, 5, 8])
@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_random_closed_loops_are_safe(seed: int, scheme: str) -> None:
    sc = random_scenario(seed)
    m = run_random(seed, scheme, t_end=min(sc.t_end, 150 * sc.sample_time))
    assert safety_violations(m) == 0, m
    assert m["min_clearance"] >= 0.0
    assert m["state_bound_violations"] == 0


@pytest.mark.parametrize("seed", [0, 3, 5, 8, 11])
def test_random_closed_loops_with_two_neighbour_slots_are_safe(seed: int) -> None:
    """Fewer slots than neighbours in reach: the first-input check keeps the rest safe."""
    from sqpmpc.control.settings import SolverSettings

    sc = random_scenario(seed)
    m = run_random(seed, "decentralized", t_end=min(sc.t_end, 150 * sc.sample_time),
                   settings=SolverSettings(neighbour_slots=2))
    assert safety_violations(m) == 0, m
    assert m["min_clearance"] >= 0.0
