"""A distributed run on a real plant: obstacles and a noisy exact plant across processes.

The plant process moves the robots with the scenario's ``[plant]`` (exact arcs, seeded
input noise) and every controller process keeps the obstacles: the lockstep run must
reproduce the in-process one exactly, noise included.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sqpmpc.problem.plant import PlantSpec
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import simulate
from tests import HANG


@pytest.mark.parametrize("scheme", ["decentralized", "centralized"])
def test_noisy_exact_plant_with_obstacles_reproduces_the_in_process_run(tmp_path: Path,
                                                                        scheme: str) -> None:
    scenario = load_scenario("corridor").with_changes(
        t_end=12.0, plant=PlantSpec("exact", (0.02, 0.03), seed=11))
    path = tmp_path / "corridor-noisy.toml"
    path.write_text(scenario.to_toml())
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "services.launch", "--scenario", str(path), "--scheme", scheme,
           "--out", str(out), "--no-plots"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=HANG,
                         cwd=Path(__file__).resolve().parent.parent)
    assert res.returncode == 0, res.stderr
    traj = np.load(out / "trajectory.npz")
    reference = simulate(scenario, scheme)
    np.testing.assert_allclose(traj["states"], reference.states, rtol=0, atol=1e-9)
    np.testing.assert_allclose(traj["plant_inputs"], reference.plant_inputs, rtol=0, atol=1e-9)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["plant"]["model"] == "exact" and metrics["plant"]["seed"] == 11
    assert metrics["obstacle_collisions"] == 0 and metrics["collisions"] == 0
    assert metrics["min_obstacle_clearance"] >= 0.0
