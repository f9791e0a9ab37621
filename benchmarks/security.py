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
2. **TLS overhead**: ``services.launch`` on paper-s2 lockstep (``--t-end``,
   default 100 s: 200 samples), alternately ``--insecure`` and with
   credentials, peer to peer and through a router; the plant's median sample
   wall time (publish states, wait for the 4 inputs, integrate).

Writes the tables into ``docs/security.md`` between its ``measured`` markers.
"""

from __future__ import annotations

import argparse
import json
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

__all__ = ["Probe", "main", "run_attacked", "wait_ready"]

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
                                             plant_ep], logs, name=f"robot-{rid}"))
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
           t_end: float, wall: float) -> str:
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
    lines += ["", END]
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


def main(argv: list[str] | None = None) -> int:
    """Entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--t-end", type=float, default=100.0,
                        help="run length, s (default 100: 200 samples of paper-s2)")
    parser.add_argument("--repeat", type=int, default=3, help="runs per overhead setting")
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args(argv)
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        reference = run_attacked(Path(tmp) / "reference", None, args.t_end)
        rows = []
        for j, probe in enumerate(PROBES):
            res = run_attacked(Path(tmp) / f"probe-{j}", probe, args.t_end)
            print(probe, res["applied"], res["metrics"]["collisions"],
                  res["metrics"]["missed_deadlines"], res["forger"], flush=True)
            rows.append((probe, res))
    overhead = bench_overhead(args.t_end, args.repeat)
    publish(render(rows, reference, overhead, args.t_end, time.time() - t0),
            None if args.no_write else DOC)
    return 0


if __name__ == "__main__":
    sys.exit(main())
