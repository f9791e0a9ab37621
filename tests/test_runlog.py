"""The incremental run record: written as the plant goes, readable after kill -9."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from services.messages import decode
from services.testing import Probe, free_ports, start_service, stop_processes
from sqpmpc.cli.main import main as cli_main
from sqpmpc.io.runlog import RECORD_FILE, RecordError, RecordWriter, read_record
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import simulate
from tests import HANG

REPO = Path(__file__).resolve().parent.parent


def _write(path: Path, steps: int, end: bool) -> tuple[object, np.ndarray, np.ndarray]:
    scenario = load_scenario("paper-s2").with_changes(t_end=steps * 0.5)
    rng = np.random.default_rng(1)
    n = scenario.n_robots
    states = rng.normal(size=(steps + 1, n, 3))
    states[0] = scenario.initial_states()
    inputs = rng.normal(size=(steps, n, 2))
    w = RecordWriter(path, scenario, "decentralized", n, states[0], {"mode": "lockstep"}, "d")
    for k in range(steps):
        w.sample(k, inputs[k], states[k + 1], np.full(n, 1e-3), int(k == 3), [1] if k else [])
    if end:
        w.end(True, {"mode": "lockstep", "missed_deadlines": 7})
    else:
        w.close()
    return scenario, states, inputs


def test_round_trip_and_end_frame(tmp_path):
    _, states, inputs = _write(tmp_path / RECORD_FILE, 10, end=True)
    rec = read_record(tmp_path)
    assert rec.completed and np.array_equal(rec.states, states)
    assert np.array_equal(rec.inputs, inputs) and rec.solver_failures == 1
    assert rec.extra["missed_deadlines"] == 7 and rec.extra["recovered_from_record"] is False


def test_a_torn_tail_keeps_every_whole_sample(tmp_path):
    path = tmp_path / RECORD_FILE
    _, states, _ = _write(path, 10, end=False)
    data = path.read_bytes()
    path.write_bytes(data[:-5])  # the writer died inside the last frame
    rec = read_record(path)
    assert not rec.completed and rec.inputs.shape[0] == 9
    assert np.array_equal(rec.states, states[:10])
    assert rec.extra["recovered_from_record"] is True
    assert rec.extra["missed_deadlines"] == 8  # robot 1 braked at samples 1..8


def test_metrics_command_rebuilds_the_outputs_and_refuses_a_folder_without_record(
        tmp_path, capsys):
    _write(tmp_path / RECORD_FILE, 10, end=False)
    assert cli_main(["metrics", str(tmp_path)]) == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["steps"] == 10 and m["completed"] is False and m["recovered_from_record"] is True
    assert np.load(tmp_path / "trajectory.npz")["states"].shape == (11, 4, 3)
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli_main(["metrics", str(empty)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no record" in err
    (empty / RECORD_FILE).write_bytes(b"\x00garbage")
    with pytest.raises(RecordError, match="not a"):
        read_record(empty)


def test_the_plant_record_equals_its_outputs(tmp_path):
    out = tmp_path / "run"
    res = subprocess.run([sys.executable, "-m", "services.launch", "--scenario", "paper-s2",
                          "--scheme", "decentralized", "--t-end", "10", "--out", str(out),
                          "--no-plots"],
                         capture_output=True, text=True, timeout=HANG, cwd=REPO)
    assert res.returncode == 0, res.stderr
    rec = read_record(out)
    traj = np.load(out / "trajectory.npz")
    assert rec.completed and np.array_equal(rec.states, traj["states"])
    assert np.array_equal(rec.inputs, traj["inputs"])
    m = json.loads((out / "metrics.json").read_text())
    assert rec.extra["missed_deadlines"] == m["missed_deadlines"]


def test_kill_9_of_the_plant_leaves_a_readable_record(tmp_path):
    rng = np.random.default_rng(int.from_bytes(os.urandom(4), "little"))
    kill_at = int(rng.integers(20, 150))
    ports = free_ports(6)
    probe_ep, plant_ep = (f"tcp/127.0.0.1:{p}" for p in ports[:2])
    probe = Probe("kill9", [], [("plant", "state")], listen=[probe_ep])
    # a run far longer than the kill sample: on a loaded machine the probe may see sample
    # `kill_at` late, and the SIGKILL must still land mid-run
    common = ["--scenario", "paper-s2", "--t-end", "2000", "--run", "kill9"]
    out = tmp_path / "out"
    plant = start_service("plant", [*common, "--listen", plant_ep, "--connect", probe_ep,
                                    "--out", str(out), "--no-plots"], tmp_path / "logs")
    robots = [start_service("robot", ["--id", str(i), *common, "--insecure", "--listen",
                                      f"tcp/127.0.0.1:{port}", "--connect", plant_ep],
                            tmp_path / "logs", name=f"robot-{i}")
              for i, port in zip((1, 2, 3, 4), ports[2:], strict=True)]
    try:

        def newest() -> int:
            return max((decode(e.payload, 8).sample for e in probe.events), default=-1)

        assert probe.wait_for(lambda: newest() >= kill_at, HANG), plant.output()
        os.kill(plant.pid, signal.SIGKILL)
        plant.wait(HANG)
        probe.wait_for(lambda: False, 0.5)  # what was still on its way (a late one: not counted)
        published = newest()
    finally:
        probe.close()
        stop_processes([plant, *robots])
    assert not (out / "metrics.json").exists()
    rec = read_record(out)
    recorded = rec.inputs.shape[0]
    # state k is published after sample k - 1 is in the record: nothing published is lost
    # (the plant may have recorded a sample or two whose states did not get out)
    assert kill_at <= published <= recorded < 4000, (published, recorded, kill_at)
    assert rec.extra["recovered_from_record"] is True and not rec.completed
    assert cli_main(["metrics", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["steps"] == recorded and m["collisions"] == 0
    # the recorded samples are the closed loop's: the in-process run has the same start
    ref = simulate(load_scenario("paper-s2").with_changes(t_end=recorded * 0.5),
                   "decentralized")
    assert np.max(np.abs(rec.states - ref.states)) <= 1e-9
