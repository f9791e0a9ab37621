"""A lifecycle that never hangs nor loses a run -> ``docs/reliability.md`` (its lifecycle part).

``python -m benchmarks.lifecycle [--launches 20] [--latest 30] [--seed 1]
[--realtime-t-end 60] [--no-write]``

1. **kill -9 and restart of one robot**: paper-s2, decentralized, the plant
   and one process per robot (Zenoh peers on 127.0.0.1, as in
   :mod:`benchmarks.faults`); robot 2 is killed with SIGKILL at sample 20 and
   started again at once with its command. In lockstep (the whole scenario)
   the plant waits for it (``--rejoin-timeout``, 30 s); in real time
   (``--realtime-t-end``, default 60 s: 120 samples at Ts 0.5 s) the others
   go on and robot 2 is braked until it is back. Reported: collisions (at /
   between samples), robots arrived (:func:`benchmarks.faults.arrival_tolerance`
   of the same run length), robot 2's braked inputs, the sample it rejoined at.
2. **A robot with no plant**: ``services.robot`` started with
   ``--startup-timeout 5`` and nothing to connect to: its exit status, its
   error lines, how long it took.
3. **SIGTERM at random times**: ``--launches`` runs of ``services.launch``
   (paper-s2, decentralized, real time: 400 s if not stopped), each sent
   SIGTERM after a uniform random delay in ``[0, --latest]`` s, counted from
   the return of ``Popen`` (the launcher exec'd, its interpreter not yet
   started). The launcher is started with SIGINT and SIGTERM blocked, as a
   supervisor that wants every stop honoured does (:mod:`services.early`): a
   signal that comes before the interpreter runs the launcher's first line is
   held by the kernel and handled there. Reported per launch: the delay, the
   exit status, ``Traceback`` lines in everything the launcher and its
   children wrote, whether a child needed SIGKILL, whether ``sqpmpc metrics``
   reads the run folder, and its samples.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from tempfile import TemporaryDirectory

import numpy as np

from benchmarks.faults import arrival_tolerance
from services.messages import decode
from services.testing import REPO, Probe, free_ports, start_service, stop_processes
from sqpmpc.problem.scenario_file import load_scenario

__all__ = ["BEGIN", "END", "main", "restart_case", "sigterm_launch"]

DOC = REPO / "docs" / "reliability.md"
BEGIN, END = "<!-- measured: benchmarks/lifecycle.py -->", "<!-- /measured lifecycle -->"
SCENARIO = "paper-s2"
NOTE = ("A launch whose SIGTERM comes before the interpreter has run the launcher's first "
        "line and whose signals were not blocked ends by the signal's default action: no "
        "traceback, no child started, nothing written, so no run folder (the rows with "
        "status -15).")


def _newest(probe: Probe, horizon: int) -> int:
    samples = [decode(e.payload, horizon).sample for e in probe.events[-20:]]
    probe.events = probe.events[-20:]
    return max(samples, default=-1)


def restart_case(mode: str, work: Path, t_end: float | None) -> dict:
    """paper-s2 with robot 2 killed at sample 20 and started again; returns the row."""
    scenario = load_scenario(SCENARIO)
    if t_end is not None:
        scenario = scenario.with_changes(t_end=t_end)
    ids = [int(i) for i in scenario.ids]
    ports = free_ports(2 + len(ids))
    probe_ep, plant_ep = (f"tcp/127.0.0.1:{p}" for p in ports[:2])
    run = f"restart-{mode}"
    probe = Probe(run, [], [("plant", "state")], listen=[probe_ep])
    common = ["--scenario", SCENARIO, "--run", run, "--log-level", "INFO",
              *(["--t-end", repr(t_end)] if t_end is not None else [])]
    out = work / "out"
    plant = start_service("plant", [*common, "--listen", plant_ep, "--connect", probe_ep,
                                    "--out", str(out), "--no-plots", "--quiet", "--mode", mode,
                                    "--timeout", "2"], work / "logs")
    extra = ["--qp-time-limit", repr(0.4 * scenario.sample_time)] if mode == "realtime" else []
    robots = {i: start_service("robot", ["--id", str(i), *common, "--insecure", "--listen",
                                         f"tcp/127.0.0.1:{port}", "--connect", plant_ep,
                                         "--timeout", "0.1", *extra],
                               work / "logs", name=f"robot-{i}")
              for i, port in zip(ids, ports[2:], strict=True)}
    procs = [plant, *robots.values()]
    t0 = time.monotonic()
    try:
        probe.wait_for(lambda: _newest(probe, scenario.horizon) >= 20, 300)
        victim = robots[ids[1]]
        victim.proc.kill()
        victim.wait(10)
        killed_at = time.monotonic()
        again = start_service("robot", victim.argv[3:], work / "logs", name="robot-2-again")
        procs.append(again)
        plant.wait(3600)
        back = time.monotonic() - killed_at
    finally:
        probe.close()
        stop_processes(procs)
    logs = "".join(p.output() for p in procs)
    m = json.loads((out / "metrics.json").read_text())
    traj = np.load(out / "trajectory.npz")
    k = traj["states"].shape[0] - 1
    tolerance, why = arrival_tolerance(SCENARIO, t_end)
    goal = scenario.reference_positions(k * scenario.sample_time)
    err = np.hypot(*(traj["states"][-1, :, :2] - goal).T)
    joined = [ln for ln in plant.output().splitlines() if "robot/2 joined at sample" in ln]
    return {
        "mode": mode, "samples": f"{k}/{scenario.steps}",
        "collisions": f"{m['collisions']} / {m.get('intersample_collisions')}",
        "arrived": f"{int((err <= tolerance).sum())}/{len(ids)}", "error": f"{err.max():.3f}",
        "braked": m["missed_deadlines_by_robot"][str(ids[1])],
        "others": sum(v for r, v in m["missed_deadlines_by_robot"].items()
                      if r != str(ids[1])),
        "rejoined": joined[-1].rsplit(" ", 1)[-1] if joined else "never",
        "restart_s": f"{back:.1f}", "wall": f"{time.monotonic() - t0:.0f}",
        "tracebacks": logs.count("Traceback"), "why": why,
    }


def silent_case(work: Path) -> dict:
    """paper-s2 in lockstep with robot 2 alive but silent from sample 20 on
    (``SQPMPC_FAULTS=mute=20``: its token stays, it publishes nothing); returns the row."""
    scenario = load_scenario(SCENARIO)
    ids = [int(i) for i in scenario.ids]
    ports = free_ports(1 + len(ids))
    plant_ep = f"tcp/127.0.0.1:{ports[0]}"
    common = ["--scenario", SCENARIO, "--run", "silent", "--log-level", "INFO"]
    out = work / "out"
    plant = start_service("plant", [*common, "--listen", plant_ep, "--out", str(out),
                                    "--no-plots", "--quiet", "--timeout", "2"], work / "logs")
    robots = [start_service("robot", ["--id", str(i), *common, "--insecure", "--listen",
                                      f"tcp/127.0.0.1:{port}", "--connect", plant_ep,
                                      "--timeout", "1"], work / "logs", name=f"robot-{i}",
                            env={**os.environ, "SQPMPC_FAULTS": "mute=20"} if i == ids[1]
                            else None)
              for i, port in zip(ids, ports[1:], strict=True)]
    t0 = time.monotonic()
    try:
        status = plant.wait(3600)
    finally:
        stop_processes([plant, *robots])
    m = json.loads((out / "metrics.json").read_text())
    traj = np.load(out / "trajectory.npz")
    k = traj["states"].shape[0] - 1
    tolerance, _ = arrival_tolerance(SCENARIO, None)
    err = np.hypot(*(traj["states"][-1, :, :2]
                     - scenario.reference_positions(k * scenario.sample_time)).T)
    others = [j for j, i in enumerate(ids) if i != ids[1]]
    return {"status": status, "samples": f"{k}/{scenario.steps}",
            "collisions": f"{m['collisions']} / {m.get('intersample_collisions')}",
            "timeouts": m["lockstep_timeouts"],
            "braked": m["missed_deadlines_by_robot"][str(ids[1])],
            "arrived": f"{int((err[others] <= tolerance).sum())}/{len(others)}",
            "waits": [r.output().count("no plan of sample") for r in robots],
            "wall": f"{time.monotonic() - t0:.0f}",
            "tracebacks": "".join(p.output() for p in [plant, *robots]).count("Traceback")}


def no_plant(work: Path) -> dict:
    """A robot started with nothing to connect to and ``--startup-timeout 5``."""
    (port,) = free_ports(1)
    t0 = time.monotonic()
    robot = start_service("robot", ["--id", "1", "--scenario", SCENARIO, "--run", "alone",
                                    "--insecure",
                                    "--connect", f"tcp/127.0.0.1:{port}",
                                    "--startup-timeout", "5"], work / "logs", name="alone")
    status = robot.wait(300)
    errors = [ln for ln in robot.output().splitlines() if " ERROR " in ln]
    return {"status": status, "errors": errors, "wall": time.monotonic() - t0,
            "tracebacks": robot.output().count("Traceback")}


def _block_stops() -> None:
    """In the launcher before ``exec``: SIGINT and SIGTERM held until its first line."""
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})


def sigterm_launch(work: Path, delay: float) -> dict:
    """One real-time launch sent SIGTERM after ``delay`` s; returns its row."""
    out = work / "run"
    launcher = subprocess.Popen(
        [sys.executable, "-m", "services.launch", "--scenario", SCENARIO, "--scheme",
         "decentralized", "--mode", "realtime", "--out", str(out), "--no-plots",
         "--log-level", "INFO"], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, preexec_fn=_block_stops)
    time.sleep(delay)
    launcher.send_signal(signal.SIGTERM)
    try:
        stdout, err = launcher.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        launcher.kill()
        stdout, err = launcher.communicate()
    res = subprocess.run([sys.executable, "-m", "sqpmpc", "metrics", str(out)],
                         capture_output=True, text=True, cwd=REPO, timeout=300)
    samples = "-"
    if res.returncode == 0 and (out / "metrics.json").exists():
        samples = json.loads((out / "metrics.json").read_text())["steps"]
    return {"delay": delay, "status": launcher.returncode,
            "tracebacks": (stdout + err).count("Traceback"), "killed": "killing" in err,
            "readable": res.returncode == 0, "samples": samples,
            "metrics": (res.stdout + res.stderr).strip().splitlines()[-1:] or [""]}


def render(restarts: list[dict], alone: dict, launches: list[dict], latest: float,
           wall: float, silent: dict | None = None) -> str:
    """The lifecycle section of ``docs/reliability.md``."""
    lines = [BEGIN, "", "## Lifecycle", "",
             f"Measured by `python -m benchmarks.lifecycle` "
             f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {wall:.0f} s on this "
             "shared 2-core machine; the module docstring says exactly what each row does).",
             "", "Every wait is bounded and every process ends with one clear line when what it "
             "depends on is gone:", "",
             "- a controller with no state from the plant gives up after `--startup-timeout` "
             "(default 120 s), status 1; one whose plant leaves (liveliness token gone, at "
             "once on a crash, after the 10 s lease on a silent partition) ends, status 1;",
             "- the plant waits `--startup-timeout` for its controllers before sample 0; in "
             "lockstep it waits up to `--rejoin-timeout` (default 30 s) for a controller that "
             "left mid-run (a restarted robot rejoins at the sample where it left), then brakes "
             "its robots; when every controller has been gone `--rejoin-timeout` it stops with "
             "one error line (`abandoned` in `metrics.json`), writes what it has, status 1;",
             "- in lockstep a controller that is alive (its liveliness token stays) but sends "
             "nothing is waited for once (the plant's `--timeout`, the neighbours' "
             "`--timeout`), then its robot is braked and nobody waits for it until it sends "
             "again (the neighbours predict it from its states); the run goes on at the "
             "others' pace;",
             "- SIGINT/SIGTERM at any moment, start-up included: each service records a signal "
             "from its first lines on (`services/early.py`, before its slow imports; one sent "
             "even earlier is held by the kernel when the service was started with the "
             "signals blocked, and handled there) and "
             "honours it once it can, without a traceback; the launcher signals a child only "
             "once it handles signals, and always starts the plant, which writes what was "
             "simulated (a run stopped before its first sample has `steps 0` and "
             "`interrupted`); `sqpmpc metrics` reads every such folder;",
             "- nothing of the credentials is left on disk by a launch, whatever its end "
             "(`docs/security.md`).", "",
             "kill -9 of robot 2 at sample 20 and its command started again at once:", "",
             "| mode | samples | collisions (at / between) | arrived | largest final error m | "
             "robot 2 braked inputs | others' braked inputs | robot 2 rejoined at sample | "
             "kill to end of run s | tracebacks | wall s |", "|" + "---|" * 11]
    for r in restarts:
        lines.append(f"| {r['mode']} | {r['samples']} | {r['collisions']} | {r['arrived']} | "
                     f"{r['error']} | {r['braked']} | {r['others']} | {r['rejoined']} | "
                     f"{r['restart_s']} | {r['tracebacks']} | {r['wall']} |")
    lines += ["", "*Arrived*: " + "; ".join(f"{r['mode']}: {r['why']}" for r in restarts)
              + ".", "",
              *([] if silent is None else [
                  "Robot 2 alive but silent from sample 20 on in lockstep (`SQPMPC_FAULTS="
                  "mute=20`: its liveliness token stays, it publishes nothing; plant "
                  f"`--timeout 2`, robots `--timeout 1`): plant status {silent['status']}, "
                  f"{silent['samples']} samples, collisions (at / between) "
                  f"{silent['collisions']}, lockstep timeouts {silent['timeouts']} (the plant "
                  "waits once, then brakes robot 2 without waiting until it sends again), "
                  f"robot 2 braked on {silent['braked']} samples, the other robots within "
                  f"the undisturbed run's tracking band at the end {silent['arrived']} (in "
                  "that run robot 2 moves; here it stands where it stopped from t = 10 s "
                  "on), waits for a plan that did not come per robot "
                  f"{silent['waits']}, {silent['wall']} s wall, {silent['tracebacks']} "
                  "tracebacks.", ""]),
              f"A robot started with no plant (`--startup-timeout 5`): exit status "
              f"{alone['status']} after {alone['wall']:.1f} s (imports included), "
              f"{len(alone['errors'])} error line: `{' '.join(alone['errors'])[-160:]}`, "
              f"{alone['tracebacks']} tracebacks.", "",
              f"{len(launches)} launches (paper-s2, decentralized, real time) sent SIGTERM at a "
              f"uniform random time in [0, {latest:g}] s after `Popen` returned (the launcher "
              "exec'd, its interpreter not yet started), each started with SIGINT/SIGTERM "
              "blocked as a supervisor that wants every stop honoured does: a signal before the "
              "launcher's first line is held by the kernel and handled there "
              "(`services/early.py`). Started from a shell without that, a SIGTERM in the "
              "first 0.06-0.2 s (before the interpreter runs the launcher) ends it by the "
              "default action with nothing started and nothing written; `sqpmpc metrics` on "
              "the folder then says in one line that it holds no record.", "",
              "| delay s | launcher status | tracebacks | a child needed SIGKILL | "
              "`sqpmpc metrics` reads the folder | samples written |", "|---|---|---|---|---|---|"]
    for r in sorted(launches, key=lambda r: r["delay"]):
        lines.append(f"| {r['delay']:.2f} | {r['status']} | {r['tracebacks']} | "
                     f"{'yes' if r['killed'] else 'no'} | {'yes' if r['readable'] else 'no'} | "
                     f"{r['samples']} |")
    total_tb = sum(r["tracebacks"] for r in launches)
    readable = sum(r["readable"] for r in launches)
    lines += ["", f"Tracebacks in all: **{total_tb}**; run folders readable by `sqpmpc "
              f"metrics`: **{readable} / {len(launches)}**.", ""]
    if any(r["status"] < 0 for r in launches):
        lines += [NOTE, ""]
    lines.append(END)
    return "\n".join(lines)


def publish(section: str, path: Path | None) -> None:
    """Print ``section`` and put it between the markers of ``path`` (appended if none)."""
    print(section)
    if path is None:
        return
    text = path.read_text()
    if BEGIN in text:
        start, end = text.index(BEGIN), text.index(END) + len(END)
        text = text[:start] + section + text[end:]
    else:
        text = text.rstrip("\n") + "\n\n" + section + "\n"
    path.write_text(text)
    print(f"wrote {path}")


def main(argv: list[str] | None = None) -> int:
    """Entry point."""
    parser = argparse.ArgumentParser(prog="benchmarks.lifecycle",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--launches", type=int, default=20)
    parser.add_argument("--latest", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--realtime-t-end", type=float, default=120.0,
                        help="t_end of the real-time restart case (s): the restarted robot is "
                             "out for its start-up (about 13 s here) and then has to converge "
                             "onto moving references (default 120; 60 left it 0.006 m outside "
                             "the band in one run of two)")
    parser.add_argument("--no-write", action="store_true")
    args = parser.parse_args(argv)
    t0 = time.monotonic()
    rng = random.Random(args.seed)
    restarts = []
    with TemporaryDirectory() as tmp:
        for mode, t_end in (("lockstep", None), ("realtime", args.realtime_t_end)):
            restarts.append(restart_case(mode, Path(tmp) / mode, t_end))
            print(restarts[-1], flush=True)
        alone = no_plant(Path(tmp) / "alone")
        print(alone, flush=True)
        silent = silent_case(Path(tmp) / "silent")
        print(silent, flush=True)
        launches = []
        for j in range(args.launches):
            launches.append(sigterm_launch(Path(tmp) / f"launch-{j}",
                                           rng.uniform(0.0, args.latest)))
            print(launches[-1], flush=True)
    publish(render(restarts, alone, launches, args.latest, time.monotonic() - t0, silent),
            None if args.no_write else DOC)
    return 0


if __name__ == "__main__":
    sys.exit(main())
