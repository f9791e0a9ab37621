"""The run figures are written as real, non-trivial PNG files."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from sqpmpc.metrics import RunRecord, write_run
from sqpmpc.plots import plot_run

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
NAMES = ["trajectories.png", "distances.png", "inputs.png"]


@dataclass(frozen=True)
class FakeWeights:
    Q: tuple[float, float] = (1.0, 1.0)
    R: tuple[float, float] = (0.5, 0.5)


@dataclass(frozen=True)
class FakeBounds:
    def input_lower(self) -> np.ndarray:
        return np.array([-0.6, -math.pi / 4])

    def input_upper(self) -> np.ndarray:
        return np.array([0.6, math.pi / 4])

    def position_lower(self) -> np.ndarray:
        return np.array([-math.inf, -math.inf])

    def position_upper(self) -> np.ndarray:
        return np.array([math.inf, math.inf])


@dataclass(frozen=True)
class CircleScenario:
    """Duck-typed scenario: robot j follows a circle of radius 1 + j/2."""

    diameters: tuple[float, ...]
    name: str = "fake-circles"
    sample_time: float = 0.5
    horizon: int = 8
    t_end: float = 50.0
    weights: FakeWeights = field(default_factory=FakeWeights)
    bounds: FakeBounds = field(default_factory=FakeBounds)

    @property
    def steps(self) -> int:
        return int(round(self.t_end / self.sample_time))

    @property
    def n_robots(self) -> int:
        return len(self.diameters)

    @property
    def ids(self) -> np.ndarray:
        return np.arange(1, self.n_robots + 1)

    def required_distances(self) -> np.ndarray:
        d = np.asarray(self.diameters, dtype=float)
        req = (d[:, None] + d[None, :]) / 2
        np.fill_diagonal(req, 0.0)
        return req

    def pairs(self) -> np.ndarray:
        return np.stack(np.triu_indices(self.n_robots, k=1), axis=1)

    def reference_positions(self, t: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t, dtype=float)[..., None]
        radius = 1.0 + 0.5 * np.arange(self.n_robots)
        phase = 0.05 * t + np.arange(self.n_robots)
        return np.stack([radius * np.cos(phase), radius * np.sin(phase)], axis=-1)


def make_record(sc: CircleScenario, k: int, completed: bool = True) -> RunRecord:
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


def test_plot_run_writes_three_pngs(tmp_path: Path) -> None:
    sc = CircleScenario(diameters=(0.3, 0.3, 0.5))  # two distinct required distances
    paths = plot_run(make_record(sc, sc.steps), tmp_path / "figs")
    assert_pngs(paths)


@pytest.mark.parametrize(("n", "k"), [(1, 30), (3, 0), (1, 0)])
def test_plot_run_partial_and_single_robot(tmp_path: Path, n: int, k: int) -> None:
    sc = CircleScenario(diameters=(0.3,) * n)
    assert_pngs(plot_run(make_record(sc, k, completed=False), tmp_path), min_bytes=5_000)


def test_write_run_with_default_plots(tmp_path: Path) -> None:
    sc = CircleScenario(diameters=(0.3, 0.3))
    m = write_run(tmp_path, make_record(sc, 20))
    assert json.loads((tmp_path / "metrics.json").read_text()) == m
    assert_pngs([tmp_path / name for name in NAMES])


def test_large_fleet_is_fast(tmp_path: Path) -> None:
    sc = CircleScenario(diameters=(0.3,) * 8, t_end=1200.0)  # 8 robots x 2400 samples
    record = make_record(sc, sc.steps)
    start = time.perf_counter()
    assert_pngs(plot_run(record, tmp_path))
    assert time.perf_counter() - start < 30.0
