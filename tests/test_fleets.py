"""Fleet scenario generators and ``sqpmpc generate``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sqpmpc.errors import ProblemError
from sqpmpc.problem.fleets import antipodal_swap, grid_to_grid, random_crossings
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import load_scenario, parse_scenario


def _checks(sc: Scenario, trips: float = 3.0) -> None:
    """Generated scenarios are valid files: round trip, no overlap, arrival time."""
    assert parse_scenario(__import__("tomllib").loads(sc.to_toml())) == sc
    x0 = sc.initial_states()[:, :2]
    goals = sc.reference_positions(0.0)
    D = sc.required_distances()
    n = sc.n_robots
    off = ~np.eye(n, dtype=bool)
    assert np.all(np.hypot(*(x0[:, None] - x0[None]).transpose(2, 0, 1))[off] > D[off])
    assert np.all(np.hypot(*(goals[:, None] - goals[None]).transpose(2, 0, 1))[off] > D[off])
    trip = np.hypot(*(goals - x0).T).max()
    assert sc.t_end >= trips * trip / 0.6 - 1e-9
    assert sc.t_end < trips * trip / 0.6 + sc.sample_time + 1e-9


@pytest.mark.parametrize("n", [2, 6, 16, 64])
def test_antipodal_swap_keeps_the_density_of_swap_6(n: int) -> None:
    sc = antipodal_swap(n)
    _checks(sc)
    radius = np.hypot(*sc.initial_states()[:, :2].T)
    np.testing.assert_allclose(radius, 3.0 * np.sqrt(n / 6.0), rtol=1e-11)
    np.testing.assert_allclose(sc.reference_positions(0.0), -sc.initial_states()[:, :2],
                               atol=1e-12)


def test_swap_6_is_the_built_in_and_the_fleet_built_ins_are_the_generator_output() -> None:
    for n in (6, 16, 64):
        built_in, generated = load_scenario(f"swap-{n}"), antipodal_swap(n)
        a, b = built_in.initial_states(), generated.initial_states()
        np.testing.assert_allclose(a[:, :2], b[:, :2], atol=1e-11)
        np.testing.assert_allclose(np.angle(np.exp(1j * (a[:, 2] - b[:, 2]))), 0.0, atol=1e-11)
        assert built_in.t_end == generated.t_end and built_in.horizon == generated.horizon


def test_random_crossings_are_seeded_and_spaced() -> None:
    a, b = random_crossings(32, seed=3), random_crossings(32, seed=3)
    assert a == b and a.name == "crossings-32-3"
    assert random_crossings(32, seed=4) != a
    _checks(a, trips=6.0)


def test_grid_flows_cross() -> None:
    sc = grid_to_grid(3, 4)
    _checks(sc, trips=6.0)
    x0, goals = sc.initial_states()[:, :2], sc.reference_positions(0.0)
    assert np.all(x0[:, 0] < 0) and np.all(goals[:, 0] > 0)
    np.testing.assert_allclose(goals[:, 1], -x0[:, 1], atol=1e-12)  # mirrored


@pytest.mark.parametrize(("call", "needle"), [
    (lambda: antipodal_swap(1), "robots must be an integer from 2"),
    (lambda: antipodal_swap(5000), "robots must be an integer from 2 to 1024"),
    (lambda: antipodal_swap(8, sample_time=0.0), "sample_time"),
    (lambda: random_crossings(8, seed=-1), "seed"),
    (lambda: random_crossings(8, seed=1, spacing=0.2), "spacing must exceed the diameter"),
    (lambda: random_crossings(200, seed=1, spacing=5.0), "cannot place 200 robots"),
    (lambda: grid_to_grid(1, 1), "rows \\* cols"),
])
def test_bad_parameters_are_refused_by_name(call, needle: str) -> None:
    with pytest.raises(ProblemError, match=needle):
        call()


def test_generate_command_writes_a_loadable_file_or_refuses_once(tmp_path: Path) -> None:
    out = tmp_path / "c.toml"
    ok = subprocess.run([sys.executable, "-m", "sqpmpc", "generate", "crossings", "--robots",
                         "8", "--seed", "2", "--out", str(out)], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    assert load_scenario(out) == random_crossings(8, seed=2)
    bad = subprocess.run([sys.executable, "-m", "sqpmpc", "generate", "swap", "--robots", "8",
                          "--seed", "2"], capture_output=True, text=True)
    assert bad.returncode == 2
    lines = [ln for ln in bad.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "--seed does not apply to 'swap'" in lines[0]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_random_crossing_of_twenty_four_arrives_without_collision(seed: int) -> None:
    """Decentralized with the default (fleet) settings: 0 collisions at and between
    samples, every robot within 0.05 m of its goal at the end, counters consistent."""
    from sqpmpc.io.metrics import compute_metrics
    from sqpmpc.sim.simulation import ClosedLoopSimulation

    scenario = random_crossings(24, seed)
    sim = ClosedLoopSimulation(scenario, "decentralized")
    record = sim.run()
    m = compute_metrics(record)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["input_bound_violations"] == 0
    goals = scenario.reference_positions(record.t[-1])
    assert np.all(np.hypot(*(record.states[-1, :, :2] - goals).T) <= 0.05)
    assert m["counters"]["samples"] == scenario.steps * scenario.n_robots
