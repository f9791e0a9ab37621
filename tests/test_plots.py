"""The run figures are written as real, non-trivial PNG files."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from sqpmpc.io.files import write_run
from sqpmpc.io.plots import plot_run
from sqpmpc.problem.scenario import Scenario
from sqpmpc.sim.record import RunRecord
from tests.scenarios import circle_scenario

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
NAMES = ["trajectories.png", "distances.png", "inputs.png", "tracking.png", "solve_time.png"]


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


def test_large_fleet_is_fast(tmp_path: Path) -> None:
    sc = circle_scenario((0.3,) * 8, t_end=1200.0)  # 8 robots x 2400 samples
    record = make_record(sc, sc.steps)
    start = time.perf_counter()
    assert_pngs(plot_run(record, tmp_path))
    assert time.perf_counter() - start < 30.0
