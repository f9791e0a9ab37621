"""The run figures are written as real, non-trivial PNG files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sqpmpc.io.files import write_run
from sqpmpc.io.plots import plot_run
from sqpmpc.problem.scenario import Scenario
from sqpmpc.sim.record import RunRecord
from tests.scenarios import circle_scenario

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
NAMES = ["trajectories.png", "distances.png", "inputs.png", "tracking.png", "solve_time.png",
         "clearance.png", "paths_by_robot.png"]


def make_record(sc: Scenario, k: int, completed: bool = True) -> RunRecord:
    rng = np.random.default_rng(3)
    t = np.arange(k + 1) * sc.sample_time
    pos = sc.reference_positions(t) + 0.05 * rng.normal(size=(k + 1, sc.n_robots, 2))
    states = np.concatenate([pos, rng.normal(size=(k + 1, sc.n_robots, 1))], axis=-1)
    inputs = rng.uniform(-0.7, 0.7, size=(k, sc.n_robots, 2))
    return RunRecord(scenario=sc, scheme="decentralized", t=t, states=states, inputs=inputs,
                     solve_times=rng.random((k, sc.n_robots)) * 1e-3, completed=completed)


def assert_pngs(paths: list[Path], min_bytes: int = 10_000) -> None:
    assert [p.name for p in paths] == NAMES
    for p in paths:
        data = p.read_bytes()
        assert data[:8] == PNG_MAGIC, p
        assert len(data) > min_bytes, (p, len(data))


def test_plot_run_writes_the_pngs(tmp_path: Path) -> None:
    sc = circle_scenario((0.3, 0.3, 0.5))  # two distinct required distances
    paths = plot_run(make_record(sc, sc.steps), tmp_path / "figs")
    assert_pngs(paths)


@pytest.mark.parametrize(("n", "k"), [(1, 30), (3, 0), (1, 0)])
def test_plot_run_partial_and_single_robot(tmp_path: Path, n: int, k: int) -> None:
    sc = circle_scenario((0.3,) * n)
    assert_pngs(plot_run(make_record(sc, k, completed=False), tmp_path), min_bytes=5_000)


def test_write_run_with_default_plots(tmp_path: Path) -> None:
    sc = circle_scenario((0.3, 0.3))
    m = write_run(tmp_path, make_record(sc, 20))
    assert json.loads((tmp_path / "metrics.json").read_text()) == m
    assert_pngs([tmp_path / name for name in NAMES])


def test_a_long_run_is_plotted(tmp_path: Path) -> None:
    sc = circle_scenario((0.3,) * 8, t_end=1200.0)  # 8 robots x 2400 samples
    record = make_record(sc, sc.steps)
    assert_pngs(plot_run(record, tmp_path))  # its speed is measured in benchmarks, not here


@pytest.mark.parametrize("n", [4, 16, 64])
def test_fleet_figures_at_4_16_and_64_robots(tmp_path: Path, n: int) -> None:
    """Every figure is drawn for a fleet (heat maps and aggregates past 8 robots)."""
    from sqpmpc.problem.fleets import antipodal_swap

    sc = antipodal_swap(n).with_changes(t_end=5.0)
    assert_pngs(plot_run(make_record(sc, sc.steps), tmp_path))


def test_the_fleet_clearance_names_the_pair_of_the_metrics() -> None:
    from sqpmpc.io.fleetplots import fleet_clearances, nearest_clearances, time_marks
    from sqpmpc.io.metrics import compute_metrics
    from sqpmpc.problem.fleets import antipodal_swap

    sc = antipodal_swap(12).with_changes(t_end=10.0)
    record = make_record(sc, sc.steps)
    metrics = compute_metrics(record)
    clear, pair = fleet_clearances(record)
    i = int(np.argmin(clear))
    assert clear[i] == pytest.approx(metrics["min_clearance"])
    assert sorted(pair[i].tolist()) == sorted(metrics["min_clearance_at"]["pair"])
    nearest, who = nearest_clearances(record)
    assert nearest.shape == who.shape == (sc.steps + 1, 12)
    np.testing.assert_allclose(nearest.min(axis=1), clear)  # the fleet's is the robots' least
    assert not np.any(who == record.ids[None, :])  # nobody is its own neighbour
    marks, step = time_marks(record.t)
    assert step == 1.0 and 8 <= marks.size <= 12
    assert fleet_clearances(make_record(circle_scenario((0.3,)), 3)) is None
