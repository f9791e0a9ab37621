"""Forged traffic against a distributed run, with and without credentials; the cost of TLS.

``python -m benchmarks.security [--t-end T] [--repeat R] [--no-write]``

1. **Forged traffic**: paper-s2 in lockstep (plant + 4 robot processes, Zenoh
   peers on loopback) while a :mod:`services.forger` process publishes, on
   every state it sees (or blind, every 20 ms), a well-formed ``cmd`` for
   robot 1, robot 1's ``plan`` 10 m away, the next sample's ``state`` with
   every robot moved, or the plant's ``done``. Without credentials
   (``--insecure`` runs) and with them (the run's mTLS + access control), the
   forger holding no certificate (plain TCP, or TLS with another CA's
   certificate) or robot 2's certificate. Reported: collisions, the samples on
   which the plant applied the forged input of robot 1, whether the run
   completed, and whether the trajectory equals the undisturbed run.
2. **Flood**: paper-s2 in real time at Ts 0.1 s while a forger holding robot
   2's certificate publishes on robot 2's own keys as fast as it can
   (well-formed messages, or 8 MB payloads), with and without the
   per-publisher limits (:mod:`services.limits`); missed deadlines of the
   other robots, collisions (``--only-floods``: these rows only).
3. **TLS overhead**: ``services.launch`` on paper-s2 lockstep (``--t-end``,
   default 100 s: 200 samples), alternately ``--insecure`` and with
   credentials, peer to peer and through a router; the plant's median sample
   wall time (publish states, wait for the 4 inputs, integrate).

Writes the tables into ``docs/security.md`` between its ``measured`` markers.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.credentials import write_credentials
from services.forger import forged_speed
from services.testing import REPO, ServiceProcess, free_ports, start_service, stop_processes
from sqpmpc.problem.scenario_file import load_scenario

__all__ = ["FLOODS", "Flood", "Probe", "main", "run_attacked", "run_flooded", "wait_ready"]

DOC = REPO / "docs" / "security.md"
BEGIN, END = "<!-- measured: benchmarks/security.py -->", "<!-- /measured -->"
SCENARIO = "paper-s2"


@dataclass(frozen=True)
class Probe:
    """One forged-traffic experiment."""

    label: str
    secured: bool
    forger: str  # "none" (no credentials), "other-ca", "robot-2"
    attack: str


PROBES = [
    Probe("no credentials in the run", False, "none", "cmd"),
    Probe("no credentials in the run", False, "none", "state"),
    Probe("no credentials in the run", False, "none", "plan"),
    Probe("no credentials in the run", False, "none", "done"),
    Probe("credentials; forger without a certificate (plain TCP)", True, "none",
          "cmd,plan,state,done,alive"),
    Probe("credentials; forger with another CA's certificate", True, "other-ca",
          "cmd,plan,state,done,alive"),
    Probe("credentials; forger holding robot 2's certificate", True, "robot-2", "cmd"),
    Probe("credentials; forger holding robot 2's certificate", True, "robot-2", "state"),
    Probe("credentials; forger holding robot 2's certificate", True, "robot-2", "plan"),
    Probe("credentials; forger holding robot 2's certificate", True, "robot-2", "done"),
]


def run_attacked(work: Path, probe: Probe | None, t_end: float) -> dict:
    """Run paper-s2 in lockstep with a forger (``None``: undisturbed, with credentials)."""
    secured = probe is None or probe.secured
    run = f"sec-{time.monotonic_ns() % 10**9}"
    creds = work / "creds"
    if secured:
        write_credentials(creds, load_scenario(SCENARIO), run, "decentralized")
    proto = "tls" if secured else "tcp"
    ports = free_ports(6)
    plant_ep = f"{proto}/127.0.0.1:{ports[0]}"
    common = ["--scenario", SCENARIO, "--run", run, "--t-end", repr(t_end), "--log-level",
              "WARNING", *(["--credentials", str(creds)] if secured else [])]
    out, logs = work / "out", work / "logs"
    procs = [start_service("plant", [*common, "--listen", plant_ep, "--out", str(out),
                                     "--no-plots", "--quiet", "--timeout", "0.5"], logs)]
    forger = None
    if probe is not None:  # it knows every endpoint (it could scan the ports)
        fargs = ["--scenario", SCENARIO, "--run", run, "--t-end", repr(t_end), "--attack",
                 probe.attack, "--duration", "600", "--log-level", "ERROR", "--links", "5"]
        for port in ports[:5]:
            fargs += ["--connect", f"{'tcp' if probe.forger == 'none' else 'tls'}"
                                   f"/127.0.0.1:{port}"]
        if probe.forger == "none":
            fargs += ["--listen", f"tcp/127.0.0.1:{ports[5]}"]
        else:
            folder = creds
            if probe.forger == "other-ca":
                folder = work / "other"
                write_credentials(folder, load_scenario(SCENARIO), run, "decentralized")
            fargs += ["--credentials", str(folder), "--identity", "robot-2", "--listen",
                      f"tls/127.0.0.1:{ports[5]}"]
        forger = start_service("forger", fargs, logs)
        wait_ready(forger, 60.0)
    for j, rid in enumerate(load_scenario(SCENARIO).ids, start=1):
        procs.append(start_service("robot", ["--id", str(rid), *common, "--listen",
                                             f"{proto}/127.0.0.1:{ports[j]}", "--connect",
                                             plant_ep, *([] if secured else ["--insecure"])],
                                   logs, name=f"robot-{rid}"))
    try:
        procs[0].wait(600)
    finally:
        stop_processes(procs[1:] + ([forger] if forger else []), grace=30.0)
    metrics = json.loads((out / "metrics.json").read_text())
    traj = np.load(out / "trajectory.npz")
    v = forged_speed(load_scenario(SCENARIO).bounds.input_upper())
    applied = int(np.sum(traj["inputs"][:, 0, 0] == v))
    summary = {}
    if forger is not None:
        lines = [ln for ln in forger.output().splitlines() if ln.startswith("{")]
        summary = json.loads(lines[-1]) if lines else {}
    return {"metrics": metrics, "states": traj["states"], "inputs": traj["inputs"],
            "applied": applied, "forger": summary}


@dataclass(frozen=True)
class Flood:
    """One flood experiment: robot 2's certificate publishing on robot 2's own keys."""

    label: str
    payload: int | None  # None: no flood; 0: well-formed messages; -1: a busy loop that
    # sends nothing (what its CPU alone costs); else bytes per payload
    limits: bool  # services.limits in the run's processes
    niced: bool  # the flooder at the lowest CPU priority (as if on a computer of its own)
    priority: str = "auto"  # services.launch --priority: the honest processes' sample loops


MAX = "well-formed messages at the highest rate"
FLOODS = [
    Flood("no flood", None, True, False),
    Flood("none: a busy loop (CPU only)", -1, True, False, "off"),
    Flood("none: a busy loop (CPU only)", -1, True, False),
    Flood(MAX, 0, True, True, "off"),
    Flood(MAX, 0, True, False, "off"),
    Flood(MAX, 0, False, False),
    Flood(MAX, 0, True, False),
    Flood("8 MB payloads", 8_000_000, False, False),
    Flood("8 MB payloads", 8_000_000, True, False),
]


def run_flooded(work: Path, flood: Flood, t_end: float) -> dict:
    """paper-s2 in real time at Ts 0.1 s (``services.launch``, credentials) while a
    forger holding robot 2's certificate floods robot 2's keys, linked to every process."""
    run = f"flood-{time.monotonic_ns() % 10**9}"
    creds = work / "creds"
    write_credentials(creds, load_scenario(SCENARIO), run, "decentralized")
    (port,) = free_ports(1)
    endpoint = f"tls/127.0.0.1:{port}"
    forger = burner = None
    if flood.payload == -1:
        burner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    elif flood.payload is not None:
        forger = start_service("forger", [
            "--scenario", SCENARIO, "--sample-time", "0.1", "--t-end", repr(t_end),
            "--run", run, "--credentials", str(creds), "--identity",
            "robot-2", "--target", "2", "--attack", "flood", "--flood-bytes", str(flood.payload),
            "--duration", "900", "--listen", endpoint, "--log-level", "ERROR"], work / "logs")
        if flood.niced:
            os.setpriority(os.PRIO_PROCESS, forger.pid, 19)
        wait_ready(forger, 60.0)
    out = work / "out"
    load = f"{os.getloadavg()[0]:.1f}"
    try:
        subprocess.run([sys.executable, "-m", "services.launch", "--scenario", SCENARIO,
                        "--scheme", "decentralized", "--mode", "realtime", "--sample-time",
                        "0.1", "--t-end", repr(t_end), "--run", run, "--credentials",
                        str(creds), "--out", str(out), "--no-plots", "--priority", flood.priority,
                        *(["--connect", endpoint] if forger else []),
                        *([] if flood.limits else ["--no-flood-limits"])],
                       cwd=REPO, capture_output=True, timeout=900)
    finally:
        if forger is not None:
            stop_processes([forger], grace=30.0)
        if burner is not None:
            burner.kill()
            burner.wait()
    summary = {}
    if forger is not None:
        lines = [ln for ln in forger.output().splitlines() if ln.startswith('{"opened"')]
        summary = json.loads(lines[-1]) if lines else {}
    return {"metrics": json.loads((out / "metrics.json").read_text()), "forger": summary,
            "load": load}


def render_floods(rows: list[tuple[Flood, dict]], t_end: float) -> list[str]:
    """The flood table of ``docs/security.md``."""
    lines = ["", f"Flood: {SCENARIO} in real time at Ts 0.1 s, {int(round(t_end / 0.1))} "
             "samples (`services.launch` with credentials, every process linked to the "
             "flooder), a `services.forger` holding robot 2's certificate publishing robot 2's "
             "`cmd` and `plan` (also addressed to robots 1, 3, 4) of the newest sample it saw "
             "in a loop without pause; "
             "limits: `services.limits` (`--max-rate` 200 Hz per key, 64 KiB payloads); "
             "flooder: `nice 19` as if it ran on a computer of its own, `nice 0` sharing the "
             "machine's 2 cores with the run; priority: `services.launch --priority` of the "
             "run's processes (`auto`: their sample loops at `SCHED_RR` 20, `off`: normal); "
             "response: from the plant publishing a sample's states to a robot's input of "
             "that sample arriving, robots 1, 3, 4 (the deadline is Ts = 100 ms after the "
             "states); load: `uptime` before the row.", "",
             "| flood | limits | flooder | priority | messages/s sent | MB/s offered | missed "
             "deadlines robots 1, 3, 4 | robot 2 | response median / p99 / max ms | "
             "collisions | completed | load (1 min) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for flood, res in rows:
        m, f = res["metrics"], res["forger"]
        by = m["missed_deadlines_by_robot"]
        others = sum(by[k] for k in ("1", "3", "4"))
        resp = [m.get("response_ms", {}).get(k) or {} for k in ("1", "3", "4")]
        worst = [max((r.get(q) or 0.0) for r in resp) for q in ("median", "p99", "max")]
        seconds = f.get("seconds") or 0.0
        rate = f"{sum(f['sent'].values()) / seconds:,.0f}" if seconds else "-"
        mb = f"{f['flood_bytes'] / seconds / 1e6:,.0f}" if seconds else "-"
        lines.append(f"| {flood.label} | {'yes' if flood.limits else 'no'} | "
                     f"{'-' if flood.payload is None else 'nice 19' if flood.niced else 'nice 0'}"
                     f" | {flood.priority} | {rate} | {mb} | {others} / {3 * m['steps']} "
                     f"({100 * others / max(3 * m['steps'], 1):.1f} %) | {by['2']} | "
                     f"{' / '.join(f'{v:.1f}' for v in worst)} | "
                     f"{m['collisions']} | {m['completed']} | {res['load']} |")
    return lines


def wait_ready(proc: ServiceProcess, timeout: float) -> None:
    """Wait until a forger printed its ready line (or exited)."""
    deadline = time.monotonic() + timeout
    while '"ready"' not in proc.output() and proc.proc.poll() is None:
        if time.monotonic() > deadline:
            raise TimeoutError(f"{proc.name} not ready in {timeout} s")
        time.sleep(0.05)


def bench_overhead(t_end: float, repeat: int) -> dict[str, list[float]]:
    """Median sample wall time of launched lockstep runs, ms, per setting."""
    settings = {"peer, --insecure": ["--insecure"], "peer, credentials (mTLS + ACL)": [],
                "router, --insecure": ["--router", "--insecure"],
                "router, credentials (mTLS + ACL)": ["--router"]}
    result: dict[str, list[float]] = {k: [] for k in settings}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeat):
            for name, extra in settings.items():
                out = Path(tmp) / f"{r}-{len(result[name])}-{name[:4]}"
                subprocess.run([sys.executable, "-m", "services.launch", "--scenario", SCENARIO,
                                "--scheme", "decentralized", "--t-end", repr(t_end), "--out",
                                str(out), "--no-plots", *extra], check=True, cwd=REPO,
                               capture_output=True)
                m = json.loads((out / "metrics.json").read_text())
                result[name].append(float(m["sample_wall_ms"]["median"]))
    return result


def render(rows: list[tuple[Probe, dict]], reference: dict, overhead: dict[str, list[float]],
           t_end: float, wall: float, floods: list[str] | None = None) -> str:
    """The measured section of ``docs/security.md``."""
    steps = reference["metrics"]["steps"]
    lines = [BEGIN, "",
             f"Measured by `python -m benchmarks.security` on {platform.processor() or 'cpu'} "
             f"({platform.python_version()}), {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"
             f", {wall:.0f} s. {SCENARIO}, lockstep, {steps} samples (t_end {t_end:g} s), plant "
             "and 4 robot processes as Zenoh peers on 127.0.0.1; a forger process "
             "(`services.forger`) publishes throughout the run.", "",
             "| run | forger | forges | forged messages sent | states the forger saw | "
             "forged cmd applied (samples) | collisions (samples) | braked inputs | "
             "completed | trajectory = undisturbed |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for probe, res in rows:
        m = res["metrics"]
        same = (res["states"].shape == reference["states"].shape
                and np.array_equal(res["states"], reference["states"])
                and np.array_equal(res["inputs"], reference["inputs"]))
        f = res["forger"]
        sent = ("n/a" if "opened" not in f else sum(f["sent"].values()) if f["opened"]
                else "could not open")
        who = {"none": "no certificate", "other-ca": "other CA's certificate",
               "robot-2": "robot 2's certificate"}[probe.forger]
        lines.append(f"| {'credentials' if probe.secured else '--insecure'} | {who} | "
                     f"{probe.attack} | {sent} | {f.get('states_seen', 'n/a')} | "
                     f"{res['applied']} / {m['steps']} | {m['collisions']} | "
                     f"{m['missed_deadlines']} | {m['completed']} | "
                     f"{'yes' if same else 'no'} |")
    lines += ["", f"Undisturbed run with credentials: {reference['metrics']['collisions']} "
              f"collisions, {steps} samples.", "",
              f"Per-sample wall time of the plant in lockstep ({SCENARIO}, {steps} samples, "
              "`services.launch`, median over the run; runs alternated):", "",
              "| transport | median sample wall ms (runs) |", "|---|---|"]
    for name, values in overhead.items():
        lines.append(f"| {name} | {np.median(values):.2f} "
                     f"({', '.join(f'{v:.2f}' for v in values)}) |")
    lines += [*(floods or []), "", END]
    return "\n".join(lines)


def publish(section: str, path: Path | None) -> None:
    """Print ``section`` and write it between the markers of ``path``."""
    print(section)
    if path is None:
        return
    text = path.read_text()
    start, end = text.index(BEGIN), text.index(END) + len(END)
    path.write_text(text[:start] + section + text[end:])
    print(f"wrote {path}")


def publish_floods(lines: list[str], path: Path | None) -> None:
    """Print the flood table and put it in place of the one between the markers of
    ``path`` (from its first line to the end marker)."""
    section = "\n".join(lines)
    print(section)
    if path is None:
        return
    text = path.read_text()
    end = text.index(END)
    start = text.find("\nFlood: ", text.index(BEGIN))
    start = end if start < 0 or start > end else start
    path.write_text(text[:start] + section + "\n\n" + text[end:])
    print(f"wrote {path}")


def main(argv: list[str] | None = None) -> int:
    """Entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--t-end", type=float, default=100.0,
                        help="run length, s (default 100: 200 samples of paper-s2)")
    parser.add_argument("--repeat", type=int, default=3, help="runs per overhead setting")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--flood-t-end", type=float, default=30.0,
                        help="length of the real-time flood runs, s (default 30: 300 samples)")
    parser.add_argument("--only-floods", action="store_true",
                        help="run the flood rows only and replace the flood table")
    args = parser.parse_args(argv)
    t0 = time.time()
    floods = []
    with tempfile.TemporaryDirectory() as tmp:
        for j, flood in enumerate(FLOODS):
            res = run_flooded(Path(tmp) / f"flood-{j}", flood, args.flood_t_end)
            print(flood, res["metrics"]["missed_deadlines_by_robot"],
                  res["metrics"]["collisions"], res["forger"], flush=True)
            floods.append((flood, res))
    flood_lines = render_floods(floods, args.flood_t_end)
    if args.only_floods:
        publish_floods(flood_lines, None if args.no_write else DOC)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        reference = run_attacked(Path(tmp) / "reference", None, args.t_end)
        rows = []
        for j, probe in enumerate(PROBES):
            res = run_attacked(Path(tmp) / f"probe-{j}", probe, args.t_end)
            print(probe, res["applied"], res["metrics"]["collisions"],
                  res["metrics"]["missed_deadlines"], res["forger"], flush=True)
            rows.append((probe, res))
    overhead = bench_overhead(args.t_end, args.repeat)
    publish(render(rows, reference, overhead, args.t_end, time.time() - t0, flood_lines),
            None if args.no_write else DOC)
    return 0


if __name__ == "__main__":
    sys.exit(main())
