"""Distributed fleets: what receiving the fleet's plans costs, and the two large runs.

``python -m benchmarks.fleet_services [--skip-plans] [--skip-realtime] [--skip-lockstep]
[--robots-per-process K] [--no-write]``

1. **Receiving plans** (:func:`bench_plans`): one robot service (robot 1 of
   ``swap-64``, 8 neighbour slots, no QP) and a sender process that publishes,
   every 20 ms, the plant's states of a sample and the 63 other robots' plans
   of the sample before, over Zenoh on loopback. The robots are placed on
   their straight antipodal paths, from the start circle to the crossing (the
   first half of a swap). Per sample the receiver drains its inbox, waits for
   the plans it needs, and reads the plans its controller would read (the slot
   selection, without the QP). Printed: the receiver's CPU time per sample
   (whole process, Zenoh's threads included, and its main thread), plans
   decoded per sample, with every plan decoded (``--decode-all-plans``, the
   behaviour before plan filtering) and with the filter; at ``Ts`` 0.5 s
   (reach 5.1 m) and 0.1 s (reach 1.26 m).
2. **Real time** (:func:`bench_realtime`): ``antipodal_swap(32,
   sample_time=0.1, horizon=20)`` (a 2 s horizon), decentralized, 8 neighbour
   slots, one process per robot, the whole swap at ``Ts = 0.1 s`` of wall
   clock.
3. **Lockstep** (:func:`bench_lockstep`): the built-in ``swap-64``, 8 neighbour
   slots, decentralized, ``--robots-per-process`` robots per process (default
   8), and the in-process run with the same settings; the largest difference
   of the trajectories.

For the runs it prints missed deadlines, samples, the per-robot step time
(median, p99), collisions and arrivals, and writes ``docs/fleet-services.md``
(unless ``--no-write``). Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from services.children import free_ports
from services.messages import PlanMsg, StateMsg, encode
from services.node import scenario_digest
from services.transport import Bus
from sqpmpc.control.settings import SolverSettings
from sqpmpc.problem.fleets import antipodal_swap
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import load_scenario

from .compare_ipopt import machine_line
from .report import publish

__all__ = ["bench_lockstep", "bench_plans", "bench_realtime", "main"]

ROOT = Path(__file__).resolve().parent.parent
DOC_PATH = ROOT / "docs" / "fleet-services.md"
#: N of the real-time swap at Ts 0.1 s (a 2 s horizon; N 8 is 0.8 s, too short to resolve it)
REALTIME_HORIZON = 20
GOAL_TOLERANCE = 0.05
"""A robot has arrived when its final position is this close to its goal, m."""
PERIOD = 0.02
"""Seconds between two samples of the plan-receiving benchmark."""
MODES = {"all": "all 63 plans (--all-plans)", "filtered": "filtered (default)",
         "none": "states only, no plans (baseline)"}


# ------------------------------------------------------------------------- receiving plans
def _placed(scenario: Scenario, samples: int) -> np.ndarray:
    """``(samples, n, 3)`` states on the straight paths, from the start to the crossing."""
    start = scenario.initial_states()
    goal = scenario.reference_positions(0.0)
    f = np.linspace(0.0, 0.5, samples)[:, None, None]
    states = np.repeat(start[None], samples, axis=0)
    states[:, :, :2] = start[None, :, :2] + f * (goal - start[:, :2])[None]
    return states


def _sender(run: str, listen: str, sample_time: float, samples: int, mode: str) -> int:
    """Publish, every :data:`PERIOD`, a sample's states and the plans of robots 2..n
    (``mode``: ``all`` on their keys, ``filtered`` to robot 1 those that may take one of
    its slots, as robots do, ``none``: no plans)."""
    from services.plans import recipients

    scenario = antipodal_swap(64, sample_time=sample_time)
    v_max = 0.6
    radius = (scenario.required_distances() + SolverSettings().collision_margin
              + 2.0 * v_max * scenario.horizon * sample_time)
    states = _placed(scenario, samples)
    digest = scenario_digest(scenario)
    ids = [int(i) for i in scenario.ids]
    n1 = scenario.horizon + 1
    with Bus(run, [listen]) as bus:
        bus.watch_liveliness()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # the receiver's token: its subscriptions exist
            event = bus.get(0.1)
            if event is not None and event.kind == "alive":
                break
        time.sleep(0.5)
        for k in range(samples):
            t0 = time.perf_counter()
            bus.put(encode(StateMsg(k, k * sample_time, tuple(ids), states[k], None, digest)),
                    "plant", "state")
            if k > 0 and mode != "none":
                for j, rid in enumerate(ids[1:], start=1):
                    plan_states = np.repeat(states[k - 1, j][None], n1, axis=0)
                    payload = encode(PlanMsg(rid, k - 1, (k - 1) * sample_time, time.time(),
                                             plan_states, np.zeros((n1 - 1, 2))))
                    if mode == "all":
                        bus.put(payload, "robot", rid, "plan")
                    elif 0 in recipients(states[k - 1], j, radius, 8, 2 * v_max * sample_time):
                        bus.put(payload, "robot", rid, "plan", 1)
            time.sleep(max(0.0, PERIOD - (time.perf_counter() - t0)))
        time.sleep(0.5)
    return 0


def _receive(sample_time: float, samples: int, mode: str) -> dict[str, float]:
    """One receiver run: CPU time per sample (process, main thread), plans decoded."""
    from services.robot import RobotNode, build_parser

    run = f"plans-{os.getpid()}-{mode}-{int(1000 * sample_time)}"
    ports = free_ports(2)
    sender_ep, own_ep = (f"tcp/127.0.0.1:{p}" for p in ports)
    sender = subprocess.Popen([sys.executable, "-m", "benchmarks.fleet_services", "--sender",
                               run, sender_ep, repr(sample_time), str(samples), mode], cwd=ROOT)
    scenario = antipodal_swap(64, sample_time=sample_time)
    argv = ["--id", "1", "--scenario", "swap-64", "--run", run, "--listen", own_ep,
            "--connect", sender_ep, "--neighbour-slots", "8", "--log-level", "ERROR"]
    args = build_parser().parse_args(argv + (["--all-plans"] if mode == "all" else []))
    node = RobotNode(scenario, args)
    node.alive.update(f"robot/{i}" for i in node.neighbours)  # stands in for 63 processes
    try:
        node.start(node.subscriptions(), signals=False)
        c = node.controller
        reads = 0
        p0 = t0 = 0.0
        for k in range(samples):
            if not node.wait_until(lambda k=k: k in node.samples, 30.0):
                raise SystemExit(f"no state of sample {k} from the sender")
            if k == 1:  # from here on every sample brings 63 plans
                p0, t0 = time.process_time(), time.thread_time()
                decoded0, received0 = node.plans.decoded, node.plans.received
            states = node.samples[k].states
            needed = set(node.needed(states)) if mode != "none" else set()
            if k > 0:
                node.wait_until(lambda k=k, needed=needed: all(
                    node.plans.has(i, k - 1) for i in needed), 1.0)
            plans = node.plans_for(k, states)
            c.select_neighbours(states)  # the controller's slots, as its step fills them
            reads += sum(plans.get(jid) is not None for _, jid in c.slot_data.neighbours)
            node.plans.prune(k - 2)
        node.wait_until(lambda: False, 2 * PERIOD)  # the last sample's plans
        cpu, thread = time.process_time() - p0, time.thread_time() - t0
        decoded = node.plans.decoded - decoded0
        received = node.plans.received - received0
    finally:
        node.close()
        sender.wait(60)
    per = samples - 1
    return {"process_ms": 1e3 * cpu / per, "main_ms": 1e3 * thread / per,
            "received": received / per, "decoded": decoded / per, "read": reads / per}


def _micro(repeat: int = 2000) -> dict[str, float]:
    """Microseconds of one plan's full decode and validation, and of its header peek."""
    from services.messages import peek_plan
    from services.validator import MessageValidator

    scenario = load_scenario("swap-64")
    validator = MessageValidator(scenario.ids, scenario.horizon)
    payload = encode(PlanMsg(2, 0, 0.0, 0.0, np.zeros((scenario.horizon + 1, 3)),
                             np.zeros((scenario.horizon, 2))))
    t0 = time.perf_counter()
    for _ in range(repeat):
        validator.check(payload, "plan", 2)
    t1 = time.perf_counter()
    for _ in range(repeat):
        peek_plan(payload)
    t2 = time.perf_counter()
    return {"decode_us": 1e6 * (t1 - t0) / repeat, "peek_us": 1e6 * (t2 - t1) / repeat,
            "bytes": len(payload)}


def bench_plans(samples: int, repeat: int) -> list[dict[str, Any]]:
    """Receiving 63 plans per sample, every plan decoded vs filtered; printed rows."""
    micro = _micro()
    print(f"one plan: {micro['bytes']} bytes, decode and validate {micro['decode_us']:.1f} us, "
          f"header peek {micro['peek_us']:.2f} us")
    rows = []
    for ts in (0.5, 0.1):
        for mode in ("all", "filtered", "none"):
            runs = [_receive(ts, samples, mode) for _ in range(repeat)]
            row = {"sample_time": ts, "mode": mode,
                   **{k: float(np.median([r[k] for r in runs])) for k in runs[0]},
                   "runs": [r["process_ms"] for r in runs]}
            rows.append(row)
            print(f"Ts {ts} s, {MODES[mode]}: process CPU {row['process_ms']:.2f} ms/sample "
                  f"(runs {', '.join(f'{v:.2f}' for v in row['runs'])}), main thread "
                  f"{row['main_ms']:.2f} ms; plans per sample: received "
                  f"{row['received']:.1f}, decoded {row['decoded']:.1f}, read {row['read']:.1f}")
    return [{"micro": micro}, *rows]


# ------------------------------------------------------------------------------ the runs
def _launch(out: Path, args: list[str], timeout: float) -> tuple[float, dict[str, Any]]:
    cmd = [sys.executable, "-m", "services.launch", "--out", str(out), "--no-plots",
           "--scheme", "decentralized", "--neighbour-slots", "8", *args]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    if res.returncode != 0 or not (out / "metrics.json").exists():
        raise SystemExit(f"launcher failed ({res.returncode}):\n{res.stderr[-4000:]}")
    return wall, json.loads((out / "metrics.json").read_text())


def _summary(m: dict[str, Any], wall: float) -> dict[str, Any]:
    """The figures of a distributed run's metrics."""
    traj_n = len(m["ids"])
    st = m["solve_time"]
    per_robot = np.array(list(st["per_robot_median_ms"].values()))
    err = m.get("final_position_errors") or {}
    arrived = sum(1 for v in err.values() if v <= GOAL_TOLERANCE) if err else None
    return {"robots": traj_n, "steps": m["steps"], "planned": m.get("planned_steps"),
            "missed": m["missed_deadlines"], "late": m.get("late_commands"),
            "collisions": m["collisions"], "inter_collisions": m.get("intersample_collisions"),
            "min_clearance": m["min_clearance"], "arrived": arrived,
            "step_median_ms": float(np.median(per_robot)), "step_p99_ms": m["_p99_ms"],
            "fallbacks": m["solver_failures"], "invalid": m["invalid_messages"],
            "loop_s": m["sample_loop_wall_s"], "wall_s": wall,
            "max_final_error": m.get("max_final_position_error")}


def _per_robot_p99(out: Path) -> float:
    """p99 over every robot's every step time, ms (from ``trajectory.npz``)."""
    st = np.load(out / "trajectory.npz")["solve_times"]
    return float(np.percentile(st, 99) * 1e3)


def _final_errors(out: Path, scenario: Scenario) -> dict[str, float]:
    traj = np.load(out / "trajectory.npz")
    goal = scenario.reference_positions(0.0)
    d = np.hypot(*(traj["states"][-1, :, :2] - goal).T)
    return {str(i): float(v) for i, v in zip(traj["ids"], d, strict=True)}


def bench_realtime(out: Path, per_process: int, router: bool = True) -> dict[str, Any]:
    """32 robots, Ts 0.1 s, the whole swap in real time."""
    scenario = antipodal_swap(32, sample_time=0.1, horizon=REALTIME_HORIZON)
    path = out / "swap-32-ts0.1.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(scenario.to_toml())
    run_out = out / f"realtime-32-{per_process}-{'router' if router else 'peers'}"
    wall, m = _launch(run_out, ["--scenario", str(path), "--mode", "realtime",
                                "--robots-per-process", str(per_process),
                                *(["--router"] if router else [])],
                      timeout=scenario.t_end + 300)
    m["_p99_ms"] = _per_robot_p99(run_out)
    m["final_position_errors"] = _final_errors(run_out, scenario)
    row = {"run": f"swap-32, Ts 0.1 s, N {scenario.horizon}, real time",
           "per_process": per_process, "router": router, **_summary(m, wall),
           "start_wall_s": m.get("start_wall_s")}
    _print_run(row)
    return row


def bench_lockstep(out: Path, per_process: int, router: bool = True) -> dict[str, Any]:
    """swap-64 lockstep over Zenoh against the in-process run."""
    from sqpmpc.sim.simulation import simulate

    scenario = load_scenario("swap-64")
    run_out = out / "lockstep-64"
    wall, m = _launch(run_out, ["--scenario", "swap-64", "--robots-per-process",
                                str(per_process), *(["--router"] if router else [])],
                      timeout=3600)
    t0 = time.perf_counter()
    reference = simulate(scenario, "decentralized", SolverSettings(neighbour_slots=8))
    in_process = time.perf_counter() - t0
    traj = np.load(run_out / "trajectory.npz")
    same_shape = traj["states"].shape == reference.states.shape
    diff = float(np.max(np.abs(traj["states"] - reference.states))) if same_shape else None
    diff_u = float(np.max(np.abs(traj["inputs"] - reference.inputs))) if same_shape else None
    m["_p99_ms"] = _per_robot_p99(run_out)
    m["final_position_errors"] = _final_errors(run_out, scenario)
    row = {"run": f"swap-64, Ts {scenario.sample_time} s, N {scenario.horizon}, lockstep",
           "per_process": per_process, "router": router, **_summary(m, wall),
           "max_state_diff": diff,
           "max_input_diff": diff_u, "in_process_s": in_process,
           "counters_equal": m["counters"] == reference.extra["counters"]}
    _print_run(row)
    print(f"  in-process run {in_process:.1f} s; max |states - in-process| {diff}, "
          f"max |inputs - in-process| {diff_u}, counters equal {row['counters_equal']}")
    return row


def _print_run(r: dict[str, Any]) -> None:
    net = "through a router" if r["router"] else "peer to peer"
    print(f"{r['run']} ({r['robots']} robots, {r['per_process']} per process, {net}): samples "
          f"{r['steps']} of {r['planned']}, missed deadlines {r['missed']} (late commands "
          f"{r['late']}), per-robot step median {r['step_median_ms']:.2f} ms, p99 "
          f"{r['step_p99_ms']:.2f} ms, collisions {r['collisions']} (between samples "
          f"{r['inter_collisions']}), min clearance {r['min_clearance']:.4f} m, arrived "
          f"{r['arrived']}/{r['robots']}, fallbacks {r['fallbacks']}, invalid messages "
          f"{r['invalid']}, sample loop {r['loop_s']:.1f} s, launcher {r['wall_s']:.1f} s")


# ---------------------------------------------------------------------------------- report
def _run_rows(rows: list[dict[str, Any]]) -> str:
    head = ("| run | robots per process | samples | missed deadlines | per-robot step median "
            "ms | p99 ms | collisions (between samples) | min clearance m | arrived | "
            "fallbacks | sample loop s |")
    out = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for r in rows:
        out.append(f"| {r['run']} | {r['per_process']} | {r['steps']} of {r['planned']} | "
                   f"{r['missed']} | {r['step_median_ms']:.2f} | {r['step_p99_ms']:.2f} | "
                   f"{r['collisions']} ({r['inter_collisions']}) | {r['min_clearance']:.4f} | "
                   f"{r['arrived']}/{r['robots']} | {r['fallbacks']} | {r['loop_s']:.1f} |")
    return "\n".join(out)


def render(plans: list[dict[str, Any]] | None, realtime: dict[str, Any] | None,
           lockstep: dict[str, Any] | None, t0: float) -> str:
    """``docs/fleet-services.md``."""
    parts = [f"""# Distributed fleets: plans over Zenoh, 32 robots in real time, 64 in lockstep

Reproduce: `python -m benchmarks.fleet_services` (module docstring: what is measured).
Every process is a Zenoh session on loopback (multicast scouting off), the runs through a
Zenoh router (`services.launch --router`).

{machine_line(t0)}
"""]
    if plans:
        micro = plans[0]["micro"]
        head = ("| Ts s | plans | process CPU ms per sample (runs) | main thread ms | plans "
                "received per sample | decoded | read by the controller |")
        rows = [head, "|" + "---|" * head.count(" | ") + "---|"]
        for r in plans[1:]:
            rows.append(f"| {r['sample_time']} | {MODES[r['mode']]} | {r['process_ms']:.2f} ("
                        f"{', '.join(f'{v:.2f}' for v in r['runs'])}) | {r['main_ms']:.2f} | "
                        f"{r['received']:.1f} | {r['decoded']:.1f} | {r['read']:.1f} |")
        parts.append(f"""## What receiving the fleet's plans costs (robot 1 of swap-64, 8 slots)

One plan is {micro['bytes']} bytes; decoding and validating it takes
{micro['decode_us']:.1f} us, peeking its header (sender, sample) {micro['peek_us']:.2f} us.
A sender process publishes every 20 ms the states and the 63 other robots' plans along the
first half of a swap; the robot's process drains them and reads what its controller reads.

{chr(10).join(rows)}

With plan filtering (the default with neighbour slots, `services/plans.py`) a robot is
sent only the plans of robots that may take one of its slots at the next sample and
decodes only those its controller reads; `--all-plans` restores receiving and decoding
every plan.
""")
    runs = [r for r in (realtime, lockstep) if r]
    if runs:
        parts.append(f"""## The large runs

{_run_rows(runs)}
""")
    if lockstep:
        seconds = lockstep["in_process_s"]
        parts.append(f"""The 64-robot lockstep run against the in-process run with the same
settings (`simulate(swap-64, "decentralized", SolverSettings(neighbour_slots=8))`,
{seconds:.1f} s): largest difference of the states **{lockstep['max_state_diff']}**, of the inputs
**{lockstep['max_input_diff']}**; counters equal: **{lockstep['counters_equal']}**.
""")
    if realtime:
        missed = realtime["missed"]
        parts.append(f"""The real-time run: {missed} missed deadlines reported by the plant over
{realtime['steps']} samples of {realtime['planned']} (each QP may take 0.4 Ts; a late input
is a braking input, counted). The scenario is `antipodal_swap(32, sample_time=0.1,
horizon=20)`: with the fleet's N = 8 at Ts = 0.1 s the horizon is 0.8 s, too short for the
swap to resolve (in process as well: 0 of 32 arrived), with N = 20 (2 s) it does.
""")
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    """Entry point."""
    if argv is None and len(sys.argv) > 1 and sys.argv[1] == "--sender":
        run, ep, ts, samples, mode = sys.argv[2:7]
        return _sender(run, ep, float(ts), int(samples), mode)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="keep the runs here")
    parser.add_argument("--samples", type=int, default=200,
                        help="samples of the plan-receiving benchmark")
    parser.add_argument("--repeat", type=int, default=3,
                        help="runs per setting of the plan-receiving benchmark")
    parser.add_argument("--robots-per-process", type=int, default=8,
                        help="robots per process of the 64-robot lockstep run")
    parser.add_argument("--realtime-per-process", type=int, default=1,
                        help="robots per process of the 32-robot real-time run")
    parser.add_argument("--skip-plans", action="store_true")
    parser.add_argument("--skip-realtime", action="store_true")
    parser.add_argument("--skip-lockstep", action="store_true")
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args(argv)
    t0 = time.time()
    resource.setrlimit(resource.RLIMIT_NOFILE, _nofile())
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        plans = None if args.skip_plans else bench_plans(args.samples, args.repeat)
        realtime = None if args.skip_realtime else bench_realtime(out,
                                                                   args.realtime_per_process)
        lockstep = None if args.skip_lockstep else bench_lockstep(out, args.robots_per_process)
    report = render(plans, realtime, lockstep, t0)
    publish(report, None if args.no_write else DOC_PATH)
    return 0


def _nofile() -> tuple[int, int]:
    """Raise the soft limit of open files to the hard one (64 sessions hold many sockets)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    return (hard if hard != resource.RLIM_INFINITY else max(soft, 65536), hard)


if __name__ == "__main__":
    sys.exit(main())
