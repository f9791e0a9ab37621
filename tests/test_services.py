"""The distributed services as real processes over real Zenoh sessions on 127.0.0.1.

Every process is a peer with multicast scouting off and explicit loopback
endpoints; nothing is mocked. The runs are shortened with ``--t-end``.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest

from services.messages import CmdMsg, PlanMsg, StateMsg, decode, encode
from services.testing import (
    Probe,
    child_pids,
    free_ports,
    pid_alive,
    start_service,
    stop_processes,
)
from sqpmpc.control.settings import SolverSettings
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.record import RunRecord
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

SCENARIO = "paper-s2"
T_END = 100.0  # 200 samples, through the first close approaches


def _launch(out: Path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "services.launch", "--scenario", SCENARIO, "--out", str(out),
           "--no-plots", *extra]
    return subprocess.run(cmd, capture_output=True, text=True,
                          cwd=Path(__file__).resolve().parent.parent)


def _in_process(scheme: str, t_end: float) -> RunRecord:
    scenario = load_scenario(SCENARIO).with_changes(t_end=t_end)
    sim = ClosedLoopSimulation(scenario, scheme, SolverSettings(),
                               SimulationOptions(decentralized_mode="shared"))
    return sim.run()


def _metrics(out: Path) -> dict:
    return json.loads((out / "metrics.json").read_text())


@pytest.mark.parametrize("scheme", ["decentralized", "centralized"])
def test_lockstep_run_reproduces_the_in_process_trajectory(tmp_path, scheme):
    out = tmp_path / "run"
    res = _launch(out, "--scheme", scheme, "--t-end", str(T_END),
                  "--timeout", str(HANG))  # the plant's lockstep wait: a hang guard only
    assert res.returncode == 0, res.stderr
    assert "collisions" in res.stdout  # the summary
    traj = np.load(out / "trajectory.npz")
    in_process = _in_process(scheme, T_END)
    reference = in_process.states
    assert traj["states"].shape == reference.shape == (201, 4, 3)
    assert list(traj["ids"]) == [1, 2, 3, 4]
    assert np.max(np.abs(traj["states"] - reference)) <= 1e-9
    m = _metrics(out)
    assert m["completed"] is True and m["scheme"] == scheme
    assert_lockstep_held(m)  # no robot braked: its own input applied at every sample
    assert m["invalid_messages"] == 0
    assert m["collisions"] == 0
    assert m["solve_time"]["total_s"] > 0
    # the controllers' counters reach the plant's metrics
    assert m["counters"] == in_process.extra["counters"]
    assert m["counters"]["samples"] == 200 * (1 if scheme == "centralized" else 4)


def test_realtime_run_completes(tmp_path):
    out = tmp_path / "rt"
    res = _launch(out, "--scheme", "decentralized", "--mode", "realtime",
                  "--sample-time", "0.05", "--t-end", "1.5")
    assert res.returncode == 0, res.stderr
    m = _metrics(out)
    assert m["completed"] is True and m["mode"] == "realtime" and m["steps"] == 30
    assert m["insecure"] is False  # the launcher's credentials, handed over in memory
    assert isinstance(m["missed_deadlines"], int)
    assert m["sample_time"] == 0.05


def test_sigterm_to_the_launcher_leaves_no_child(tmp_path):
    out = tmp_path / "term"
    cmd = [sys.executable, "-m", "services.launch", "--scenario", SCENARIO, "--scheme",
           "decentralized", "--mode", "realtime", "--out", str(out), "--no-plots"]
    launcher = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                cwd=Path(__file__).resolve().parent.parent)
    try:
        children: list[int] = []
        while launcher.poll() is None and len(children) < 5:  # however long they take
            children = child_pids(launcher.pid)
            time.sleep(0.1)
        assert len(children) == 5, "plant and 4 robots should be running"
        record = out / "record.msgpack"  # the plant appends one entry per sample
        while launcher.poll() is None and not (record.exists() and record.stat().st_size > 0):
            time.sleep(0.1)
        time.sleep(1.0)  # the realtime loop is running (Ts = 0.5 s)
        launcher.send_signal(signal.SIGTERM)
        _, err = launcher.communicate()
    finally:
        if launcher.poll() is None:
            launcher.kill()
            launcher.wait()
    assert launcher.returncode == 128 + signal.SIGTERM, err
    assert "killing" not in err  # every child left on its own signal, none needed SIGKILL
    assert not [pid for pid in children if pid_alive(pid)]
    m = _metrics(out)  # the plant wrote what it had
    assert m["completed"] is False and m["interrupted"] == "SIGINT"


def _start_run(tmp_path: Path, run: str, ids: list[int], t_end: float, **kwargs):
    """:func:`tests.service_helpers.start_run` of this file's scenario."""
    return start_run(tmp_path, run, ids, t_end, scenario=SCENARIO, **kwargs)


def test_invalid_messages_are_dropped_and_counted(tmp_path):
    run = "invalid"
    # the plant's waits (for the 4 controllers before sample 0, for a sample's inputs):
    # hang guards only
    probe, plant, robots, plant_ep = _start_run(
        tmp_path, run, [1, 2, 3], 10.0,
        plant_args=("--startup-timeout", str(HANG), "--timeout", str(HANG)))
    procs = [plant, *robots.values()]
    try:
        assert probe.wait_alive(["plant", "robot/1", "robot/2", "robot/3"], HANG), probe.alive
        good_cmd = msgpack.unpackb(encode(CmdMsg(1, 0, np.zeros(2), 0.0)), raw=False)
        bad_version = msgpack.packb({**good_cmd, "v": 99}, use_bin_type=True)
        nan_u = encode(CmdMsg(1, 0, np.array([np.nan, 0.0]), 0.0))
        # seen by the plant (subscribed to robot/*/cmd): 5 invalid
        probe.put(b"\x00garbage\xff", "robot", 1, "cmd")
        probe.put(bad_version, "robot", 1, "cmd")
        probe.put(nan_u, "robot", 1, "cmd")
        probe.put(encode(CmdMsg(1, 0, np.zeros(2), 0.0)), "robot", 2, "cmd")  # id mismatch
        probe.put(encode(CmdMsg(1, 50, np.zeros(2), 0.0)), "robot", 1, "cmd")  # future sample
        probe.put(encode(CmdMsg(99, 0, np.zeros(2), 0.0)), "robot", 99, "cmd")  # unknown id
        # seen by robots 1 and 3 (subscribed to robot 2's plan) and the plant (robot/*/plan,
        # for its recording): 1 invalid each
        plan = PlanMsg(2, 0, 0.0, 0.0, np.zeros((8, 3)), np.zeros((8, 2)))  # wrong shape
        probe.put(encode(plan), "robot", 2, "plan")
        # seen by robots 1, 2, 3: 1 invalid each (unknown ids)
        probe.put(encode(StateMsg(0, 0.0, (1, 2, 3, 5), np.zeros((4, 3)))), "plant", "state")
        time.sleep(0.5)
        # now the last robot: the run starts
        robots[4] = start_service("robot", ["--id", "4", "--scenario", SCENARIO, "--t-end",
                                            "10.0", "--run", run, "--connect", plant_ep,
                                            "--insecure"],
                                  tmp_path / "logs", name="robot-4")
        procs.append(robots[4])
        assert plant.wait(HANG) == 0, plant.output()
        for r in robots.values():
            assert r.wait(HANG) == 0, r.output()
    finally:
        probe.close()
        stop_processes(procs)
    m = _metrics(tmp_path / "out")
    by_process = m["invalid_messages_by_process"]
    assert m["insecure"] is True  # plain TCP, the robots started with --insecure
    assert by_process["plant"] == 7, plant.output()
    assert by_process["robot/1"] == 2 and by_process["robot/3"] == 2
    assert by_process["robot/2"] == 1 and by_process["robot/4"] == 0
    assert m["invalid_messages"] == 12
    # the forged messages changed nothing: every input arrived, the run completed
    assert m["completed"] is True
    assert_lockstep_held(m)
    assert "dropped an invalid message" in plant.output()


def test_a_robot_that_dies_does_not_stop_the_others(tmp_path):
    run = "kill"
    probe, plant, robots, _ = _start_run(
        # 3000 samples: far more than the test needs to stop robot 2 after sample 20
        tmp_path, run, [1, 2, 3, 4], 1500.0, plant_args=("--timeout", "0.3",
                                                          "--rejoin-timeout", "1"),
        robot_args=("--timeout", "0.05"), subscriptions=(("plant", "state"),))
    procs = [plant, *robots.values()]
    try:

        def reached(k: int) -> bool:
            return any(decode(e.payload, 8).sample >= k for e in probe.events)

        assert probe.wait_for(lambda: reached(20), HANG), plant.output()
        robots[2].proc.send_signal(signal.SIGSTOP)  # silent: the plant times out on it
        # however long a busy machine makes the plant take to see it (not a fixed 1 s)
        assert probe.wait_for(lambda: re.search(r"no input from robots \[[\d, ]*\b2\b",
                                                plant.output()) is not None, HANG), \
            plant.output()
        robots[2].proc.kill()  # then gone: its liveliness token disappears
        robots[2].wait(HANG)
        assert plant.wait(HANG) == 0, plant.output()
        for i in (1, 3, 4):
            assert robots[i].wait(HANG) == 0, robots[i].output()
    finally:
        probe.close()
        stop_processes(procs)
    # invariants only (how many deadlines a loaded machine costs the others is not asserted)
    m = _metrics(tmp_path / "out")
    assert m["completed"] is True and m["steps"] == 3000 and m["collisions"] == 0
    missed = m["missed_deadlines_by_robot"]
    assert missed["2"] >= 1 and m["missed_deadlines"] == sum(missed.values())
    assert m["lockstep_timeouts"] >= 1  # while robot 2 was stopped
    assert "robot/2 is gone" in plant.output()
    for i in (1, 3, 4):  # the others saw it go (and predict it as an obstacle from then on)
        assert "robot/2 is gone" in robots[i].output()
    traj = np.load(tmp_path / "out" / "trajectory.npz")
    moved = np.flatnonzero(np.any(traj["inputs"][:, 1] != 0.0, axis=1))
    last = int(moved[-1]) + 1 if moved.size else 0  # robot 2 brakes from its stop to the end
    assert 20 <= last < 3000 and missed["2"] >= 3000 - last
    assert np.any(traj["inputs"][last:, [0, 2, 3]] != 0.0)  # the others move on


def test_a_robot_started_late_joins_the_running_loop(tmp_path):
    """Robot 4 is started once the loop runs, joins it, and drives from the sample it joined.

    Nothing here depends on how fast the machine is: the run is far longer than the test
    (60,000 samples), and the test stops it (SIGINT: the plant writes what it simulated)
    once robot 4 has joined and driven 100 samples, however long its start-up took."""
    run = "late"
    t_end = "30000.0"  # 60,000 samples: minutes of lockstep, far longer than the test
    probe, plant, robots, plant_ep = _start_run(
        tmp_path, run, [1, 2, 3], float(t_end), plant_args=("--startup-timeout", "5"),
        robot_args=("--timeout", "0.2"),  # their wait for all neighbours at the start
        subscriptions=(("plant", "state"),))
    procs = [plant, *robots.values()]
    try:
        assert probe.wait_for(lambda: bool(probe.events), HANG), plant.output()  # running
        robots[4] = start_service("robot", ["--id", "4", "--scenario", SCENARIO, "--run", run,
                                            "--t-end", t_end, "--connect", plant_ep, "--insecure",
                                            "--startup-timeout", "120"],
                                  tmp_path / "logs", name="robot-4")
        procs.append(robots[4])

        def joined() -> re.Match[str] | None:
            return re.search(r"robot/4 joined at sample (\d+)", plant.output())

        assert probe.wait_for(lambda: joined() is not None, HANG), plant.output()
        k = int(joined().group(1))
        assert probe.wait_for(lambda: newest_sample(probe) >= k + 100, HANG), plant.output()
        plant.proc.send_signal(signal.SIGINT)  # the plant writes what it simulated
        assert plant.wait(HANG) == 128 + signal.SIGINT, plant.output()
        for r in robots.values():
            r.wait(HANG)
    finally:
        probe.close()
        stop_processes(procs)
    assert "Traceback" not in plant.output() + "".join(r.output() for r in robots.values())
    # invariants only: how many deadlines a loaded machine costs is not asserted
    m = _metrics(tmp_path / "out")
    missed = m["missed_deadlines_by_robot"]
    assert m["completed"] is False and m["steps"] >= k + 100 and m["collisions"] == 0
    assert m["intersample_collisions"] == 0
    assert sum(missed.values()) == m["missed_deadlines"]
    assert missed["4"] >= k, "robot 4 braked until it joined"
    traj = np.load(tmp_path / "out" / "trajectory.npz")
    assert np.all(traj["inputs"][:k, 3] == 0.0)
    assert np.any(traj["inputs"][k:, 3] != 0.0)  # then drove
    assert np.all(np.any(traj["inputs"][:, :3] != 0.0, axis=(0, 2)))  # the others drove


@pytest.mark.parametrize("module,args", [
    ("plant", ["--scenario", "no-such-scenario"]),
    ("robot", ["--id", "1", "--scenario", "no-such-scenario"]),
    ("robot", ["--id", "9", "--scenario", SCENARIO]),
    ("central", ["--scenario", SCENARIO, "--t-end", "0.3"]),
    ("robot", ["--id", "1", "--scenario", SCENARIO, "--insecure", "--listen", "not-an-endpoint"]),
    ("router", ["--listen", "tcp/127.0.0.1:not-a-port"]),
    ("plant", ["--scenario", SCENARIO, "--credentials-fd", "99"]),
    ("launch", ["--scenario", "no-such-scenario", "--scheme", "centralized"]),
    ("launch", ["--scenario", SCENARIO, "--scheme", "centralized", "--run", "a/b"]),
])
def test_bad_input_gives_one_message_and_status_2(module, args):
    res = subprocess.run([sys.executable, "-m", f"services.{module}", *args],
                         capture_output=True, text=True, timeout=HANG,
                         cwd=Path(__file__).resolve().parent.parent)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"services.{module}: error: "), res.stderr
    assert "Traceback" not in res.stderr


def test_lockstep_fleet_with_neighbour_slots_reproduces_the_in_process_run(tmp_path):
    """Five processes (a swap of 4 robots, 2 slots each: 3 neighbours, one over the budget)
    over Zenoh equal the in-process run. (A swap of 8 took nine processes, ~2 s of CPU each
    to start, for the same property: more neighbours than slots, chosen alike.)"""
    from sqpmpc.problem.fleets import antipodal_swap
    from sqpmpc.sim.simulation import simulate

    scenario = antipodal_swap(4).with_changes(t_end=15.0)
    path = tmp_path / "swap-4.toml"
    path.write_text(scenario.to_toml())
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "services.launch", "--scenario", str(path), "--out", str(out),
           "--no-plots", "--scheme", "decentralized", "--neighbour-slots", "2"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=HANG,
                         cwd=Path(__file__).resolve().parent.parent)
    assert res.returncode == 0, res.stderr
    reference = simulate(scenario, "decentralized", SolverSettings(neighbour_slots=2))
    traj = np.load(out / "trajectory.npz")
    assert np.max(np.abs(traj["states"] - reference.states)) <= 1e-9
    m = _metrics(out)
    assert m["collisions"] == 0 and m["counters"] == reference.extra["counters"]
    assert m["counters"]["unslotted_neighbours"] > 0  # the budget was exceeded


def test_a_run_no_controller_ever_answered_is_not_a_success(tmp_path):
    """The plant alone: it runs its samples braking every robot, then says so and exits 3."""
    (port,) = free_ports(1)
    plant = start_service("plant", ["--scenario", SCENARIO, "--t-end", "1.5", "--run",
                                    "alone", "--listen", f"tcp/127.0.0.1:{port}",
                                    "--startup-timeout", "0.5", "--timeout", "0.2",
                                    "--out", str(tmp_path / "out"), "--no-plots"],
                          tmp_path / "logs")
    try:
        assert plant.wait(HANG) == 3, plant.output()
    finally:
        stop_processes([plant])
    m = _metrics(tmp_path / "out")
    assert m["completed"] is True and m["never_controlled"] == [1, 2, 3, 4]
    assert m["missed_deadlines"] == 4 * m["steps"]
    assert "no controller ever sent an input for robots 1, 2, 3, 4" in plant.output()
    assert "Traceback" not in plant.output()


def test_a_robot_killed_and_restarted_rejoins_the_lockstep_run(tmp_path):
    """kill -9 of robot 2 at sample 20 of a lockstep run (silent from there, so the run
    waits for it at 20 however slow the machine), then its command again: the plant waits
    for it (``--rejoin-timeout``) and it rejoins at the sample where it left."""
    run = "rejoin"
    probe, plant, robots, plant_ep = _start_run(
        tmp_path, run, [1, 2, 3, 4], T_END,
        plant_args=("--rejoin-timeout", str(HANG), "--timeout", str(HANG)),  # hang guards
        subscriptions=(("plant", "state"),), muted={2: 20})
    procs = [plant, *robots.values()]
    try:
        kill_and_restart(probe, plant, robots, procs, 2, 20, tmp_path / "logs")
    finally:
        probe.close()
        stop_processes(procs)
    m = _metrics(tmp_path / "out")
    assert m["completed"] is True and m["collisions"] == 0
    assert m["missed_deadlines"] <= 1  # the sample it was killed in, at most
    assert "robot/2 left at sample" in plant.output()
    assert "robot/2 joined at sample" in plant.output()
    final = np.load(tmp_path / "out" / "trajectory.npz")["states"][-1]
    reference = _in_process("decentralized", T_END).states[-1]
    assert np.max(np.hypot(*(final[:, :2] - reference[:, :2]).T)) < 0.1  # the fleet arrives


def test_every_process_ends_with_one_line_when_the_others_are_gone(tmp_path):
    """A robot with no plant gives up after --startup-timeout; a plant whose controllers all
    left gives up after --rejoin-timeout and writes what it has."""
    (port,) = free_ports(1)
    alone = start_service("robot", ["--id", "1", "--scenario", SCENARIO, "--run", "nobody",
                                    "--insecure",
                                    "--connect", f"tcp/127.0.0.1:{port}",
                                    "--startup-timeout", "2"], tmp_path / "logs",
                          name="robot-alone")
    run = "orphan"
    probe, plant, robots, _ = _start_run(tmp_path, run, [1, 2, 3, 4], 3000.0,
                                         plant_args=("--rejoin-timeout", "2"),
                                         subscriptions=(("plant", "state"),))
    procs = [alone, plant, *robots.values()]
    try:
        assert alone.wait(HANG) == 1, alone.output()
        assert probe.wait_for(lambda: newest_sample(probe) >= 5, HANG), plant.output()
        for r in robots.values():
            r.proc.kill()
        assert plant.wait(HANG) == 1, plant.output()
    finally:
        probe.close()
        stop_processes(procs)
    errors = [ln for ln in alone.output().splitlines() if "ERROR" in ln]
    assert len(errors) == 1 and "no state from the plant within 2 s" in errors[0]
    errors = [ln for ln in plant.output().splitlines() if "ERROR" in ln]
    assert len(errors) == 1 and "every controller left" in errors[0], plant.output()
    m = _metrics(tmp_path / "out")
    assert m["completed"] is False and m["abandoned"] and m["steps"] >= 5
    assert "Traceback" not in alone.output() + plant.output()


def test_oversized_and_too_frequent_messages_are_dropped_before_the_service(tmp_path):
    """Zenoh's interceptors (services.limits) drop a payload above 64 KiB and what a robot
    key carries faster than --max-rate before the plant's Python sees them."""
    run = "limits"
    (port,) = free_ports(1)
    plant = start_service("plant", ["--scenario", SCENARIO, "--run", run, "--listen",
                                    f"tcp/127.0.0.1:{port}", "--max-rate", "20",
                                    "--startup-timeout", "600", "--out", str(tmp_path / "out"),
                                    "--no-plots"], tmp_path / "logs")
    probe = Probe(run, [f"tcp/127.0.0.1:{port}"])
    try:
        assert probe.wait_alive(["plant"], HANG), plant.output()
        probe.put(b"\x00" * (1 << 17), "robot", 1, "cmd")  # 128 KiB: dropped by Zenoh
        time.sleep(0.2)
        start = time.monotonic()
        for _ in range(2000):  # small garbage, as fast as it goes: a few per 50 ms pass
            probe.put(b"\x00garbage", "robot", 3, "cmd")
        probe.put(b"\x00garbage", "robot", 4, "cmd")  # another key: its own budget
        # the plant handled that last one, so everything before it over the same link
        # (not a fixed 1 s that a busy machine can outlast)
        assert probe.wait_for(lambda: "robot 4: inconsistent input dropped" in plant.output(),
                              HANG), plant.output()
    finally:
        probe.close()
        stop_processes([plant])
    window = time.monotonic() - start  # every robot 3 message reached the plant within it
    m = _metrics(tmp_path / "out")
    faulty = m["faulty_messages"]
    assert faulty["1"] == 0 and faulty["4"] == 1
    assert 1 <= faulty["3"] <= 2 + 20 * window and faulty["3"] < 2000
    assert m["invalid_messages_by_process"]["plant"] == faulty["3"] + faulty["4"]
