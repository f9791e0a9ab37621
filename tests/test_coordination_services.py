"""The coordination rule in the distributed runtime: a maze scenario that declares its
roadmap, run as real processes over real Zenoh sessions on 127.0.0.1 (peers, multicast
scouting off, nothing mocked), equals the in-process run.

No process coordinates the others: every controller process computes the fleet's plan
from the scenario and counts every robot's progress from the states the plant sends,
so the robot processes enter every roadmap vertex in the plan's order exactly as one
process does.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from services.testing import stop_processes
from sqpmpc.control.settings import SolverSettings
from sqpmpc.problem.movingai import mapf_scenario
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.rules.registry import default_rules
from sqpmpc.sim.simulation import ClosedLoopSimulation, SimulationOptions
from tests import HANG
from tests.service_helpers import (
    assert_lockstep_held,
    kill_and_restart,
    newest_sample,
    start_run,
)

# a guard against a hang only (no budget on how long a right run takes on a busy machine)
pytestmark = pytest.mark.timeout(900)

REPO = Path(__file__).resolve().parent.parent
DATA = Path(__file__).parent / "data"
ROBOTS = 5
T_END = 14.0  # 70 samples: every robot has arrived (in process by t = 12 s)


def _maze(tmp_path: Path) -> Path:
    """Five robots between random free cells (seed 1) of the one-cell maze (their plan's
    paths cross; whether one waits for another depends on the plan)."""
    scenario = mapf_scenario(DATA / "maze-12-8.map", ROBOTS, cell=0.5, diameter=0.3,
                             acceleration=2.0, angular_acceleration=10.0, seed=1)
    path = tmp_path / "maze-12-8-5.toml"
    path.write_text(scenario.to_toml())
    return path


@pytest.mark.parametrize("scheme", ["decentralized", "centralized"])
def test_lockstep_coordination_run_reproduces_the_in_process_run(tmp_path, scheme):
    path = _maze(tmp_path)
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "services.launch", "--scenario", str(path), "--out", str(out),
           "--no-plots", "--scheme", scheme, "--t-end", str(T_END),
           "--timeout", str(HANG)]  # the plant's lockstep wait: a hang guard only
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
    assert res.returncode == 0, res.stderr

    scenario = load_scenario(path).with_changes(t_end=T_END)  # the file the processes read
    assert scenario.roadmap is not None  # so coordination alone is on by default
    reference = ClosedLoopSimulation(
        scenario, scheme, SolverSettings(rules=default_rules(scenario)),
        SimulationOptions(decentralized_mode="shared")).run()
    counters = reference.extra["counters"]
    traj = np.load(out / "trajectory.npz")
    steps = round(T_END / scenario.sample_time)
    assert traj["states"].shape == reference.states.shape == (steps + 1, ROBOTS, 3)
    assert list(traj["ids"]) == list(range(1, ROBOTS + 1))
    # the same run: a different decision anywhere in the loop would move the states by far
    # more; round-off of the processes' own arithmetic stays far below this (1.001e-9 seen
    # once against a bound of 1e-9)
    assert np.max(np.abs(traj["states"] - reference.states)) <= 1e-7

    m = json.loads((out / "metrics.json").read_text())
    assert m["completed"] is True and m["scheme"] == scheme
    assert_lockstep_held(m)  # no robot braked: its own input applied at every sample
    assert m["invalid_messages"] == 0
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0 and m["input_bound_violations"] == 0
    # the controllers' counters (the rule's among them) reach the plant's metrics
    assert m["counters"] == counters
    assert counters["samples"] == steps * (1 if scheme == "centralized" else ROBOTS)
    assert counters["coordination_tracked"] > 0  # the rule steered every robot's way
    goals = scenario.reference_positions(T_END)
    final = np.hypot(*(traj["states"][-1, :, :2] - goals).T)
    assert np.all(final <= 0.05), final  # every robot arrived
    assert m["all_arrived"] is True


def test_a_robot_killed_and_restarted_mid_run_rejoins_in_plan_order_and_arrives(tmp_path):
    """kill -9 of robot 2's controller at sample 15 of a lockstep run (silent from there, so
    the run waits for it at 15 however slow the machine), then its command again: there is
    no coordinating process to lose; the restarted controller plans anew
    from the scenario, counts every robot's progress from the states of the sample it
    joins at (``Execution.resume``) and every robot arrives, 0 collisions."""
    path = _maze(tmp_path)
    run = "coordination-rejoin"
    probe, plant, robots, _ = start_run(
        tmp_path, run, list(range(1, ROBOTS + 1)), T_END, scenario=str(path),
        plant_args=("--rejoin-timeout", str(HANG), "--timeout", str(HANG)),  # hang guards
        subscriptions=(("plant", "state"),), muted={2: 15})
    procs = [plant, *robots.values()]
    try:
        kill_and_restart(probe, plant, robots, procs, 2, 15, tmp_path / "logs")
    finally:
        probe.close()
        stop_processes(procs)
    assert "robot/2 left at sample" in plant.output()
    assert "robot/2 joined at sample" in plant.output()
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["completed"] is True and m["missed_deadlines"] <= 1  # the sample it was killed in
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0
    assert m["counters"]["coordination_tracked"] > 0
    scenario = load_scenario(path)
    final = np.load(tmp_path / "out" / "trajectory.npz")["states"][-1]
    error = np.hypot(*(final[:, :2] - scenario.reference_positions(T_END)).T)
    assert np.all(error <= 0.05), error  # every robot arrived


def test_a_robot_killed_for_good_is_told_to_every_controller_and_planned_standing(tmp_path):
    """kill -9 of robot 2's controller at sample 15 of a lockstep run, not started again:
    after ``--rejoin-timeout`` the plant says so in its states message (``gone``), every
    other controller plans again at that sample with robot 2 standing
    (``coordination_departures``: one per controller), robot 2 is braked and stands, the run
    completes with 0 collisions of any kind."""
    path = _maze(tmp_path)
    run = "coordination-gone"
    probe, plant, robots, _ = start_run(
        tmp_path, run, list(range(1, ROBOTS + 1)), T_END, scenario=str(path),
        plant_args=("--rejoin-timeout", "1", "--timeout", str(HANG)),
        subscriptions=(("plant", "state"),), muted={2: 15})
    procs = [plant, *robots.values()]
    try:
        assert probe.wait_for(lambda: newest_sample(probe) >= 15, HANG), plant.output()
        robots[2].proc.kill()
        robots[2].wait(HANG)
        assert plant.wait(HANG) == 0, plant.output()
        for rid, r in robots.items():
            if rid != 2:
                assert r.wait(HANG) == 0, r.output()
    finally:
        probe.close()
        stop_processes(procs)
    assert "robot/2 did not rejoin within 1 s" in plant.output()
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["completed"] is True
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0 and m["input_bound_violations"] == 0
    assert m["counters"]["coordination_departures"] == ROBOTS - 1
    states = np.load(tmp_path / "out" / "trajectory.npz")["states"]
    # braked from the sample the plant stopped waiting for it: it stands from then on
    assert np.hypot(*(states[-1, 1, :2] - states[-5, 1, :2])) <= 1e-6
