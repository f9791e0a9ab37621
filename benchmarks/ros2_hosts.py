"""A ROS 2 fleet with every robot on a host of its own, loss and delay between hosts.

``sudo python -m benchmarks.ros2_hosts [--scenario swap-16] [--loss 0.05]
[--delay 0.02] [--repeat 3] [--t-end-factor 1] [--no-write]`` (root: network namespaces)

``--repeat`` runs of :mod:`services.ros2.hosts`, one table row each: one network namespace per robot
holding its ``sqpmpc robot --ros2`` process, its simulated ROS 2 robot and
its ROS 2 router, a hub namespace with the sqpmpc router (mutual TLS), the
fleet's ROS 2 router and the delaying relay; ``--loss`` of the packets
dropped at random in each direction of every host's link (iptables), every
host's link ``--delay`` s longer each way (the relay). Before the fleet
starts, the first and last host's links are measured (UDP round trips to the
hub, TCP round trips through the relay); during the run the loss rules count
the packets they saw and dropped. Writes the section ``hosts`` of
``docs/ros2.md`` (:mod:`benchmarks.ros2` keeps it when it rewrites the rest).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from tempfile import TemporaryDirectory

from benchmarks.faults import arrival_tolerance
from benchmarks.ros2 import OUT, log_counts, section
from services.netns import lab_problem
from services.ros2 import hosts
from sqpmpc.problem.scenario_file import load_scenario

__all__ = ["main", "report"]


def _row(folder: Path, scenario: str, run: int, wall: float, status: int) -> str:
    """One run's row of the table."""
    check = folder / "check.json"
    if not check.exists():
        return f"| {scenario} #{run} | failed (status {status}) ||||||||||||||"
    lab = json.loads((folder / "lab.json").read_text())
    r = json.loads(check.read_text())
    c = log_counts(folder / "logs")
    cut_file = folder / "check-scenario-t_end.json"
    cut = json.loads(cut_file.read_text()) if cut_file.exists() else r
    arrivals = cut.get("arrival_times", {}).values()
    last = "-" if not arrivals or None in arrivals else f"{max(arrivals):.1f}"
    return (f"| {scenario} #{run}, {len(lab.get('packets', {}))} hosts | {r['robots']} | "
            f"{r['collisions']} | {r['min_clearance']:.3f} ({r['certified_clearance']:.3f}) | "
            f"{cut['arrived']}/{cut['robots']} ({max(cut['final_errors'].values()):.3f}) | "
            f"{last} | {r['arrived']}/{r['robots']} ({max(r['final_errors'].values()):.3f}) | "
            + " | ".join(str(c.get(k, 0)) for k in (
                "samples", "brakes", "shifted_plans", "phase_shifts", "plan_waits",
                "late_samples", "plans_received")) + f" | {wall:.0f} |")


def report(runs: list[tuple[Path, float, int]], scenario: str, loss: float, delay: float,
           why: str, lead: float) -> str:
    """The doc section of the runs ``(output folder, wall s, exit status)``."""
    labs = [json.loads((f / "lab.json").read_text()) for f, _, _ in runs
            if (f / "lab.json").exists()]
    lab = labs[0] if labs else {}
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    lines = [
        "<!-- hosts -->", "## Every robot a host of its own", "",
        f"`sudo python -m benchmarks.ros2_hosts --repeat {len(runs)}` ({date}): "
        f"`python -m services.ros2.hosts --scenario {scenario} --loss {loss:g} --delay "
        f"{delay:g} --lead {lead:g}` {len(runs)} times in a row on this machine (2 cores "
        "shared by every process). Each robot's controller, its simulated ROS 2 robot and "
        "its ROS 2 router run in a network namespace of their own (a host); a hub "
        "namespace holds the sqpmpc router (mutual TLS, access control), the fleet's ROS 2 "
        "router (each host's router joins it) and the relay; each host is joined to the "
        "hub by a veth link of its own. On every host's link: "
        f"{100 * loss:g} % of the packets dropped at random in each direction (iptables "
        f"`statistic` in the host's namespace) and {1000 * delay:g} ms more each way (the "
        "relay holds every byte that long: this kernel has no `netem`). A plan from one "
        "robot to another crosses two such links (its host's, the other's): "
        f"{2000 * delay:g} ms one way and the loss of both. The relay terminates TCP on "
        "both sides: a lost packet is resent by the TCP of its link (at least 200 ms on "
        "Linux), which is where the loss shows.", "",
        "Links, measured before the first run's fleet started (UDP datagrams echoed by the "
        "hub over the link; 64-byte TCP messages echoed through the relay):", "",
        "| host | round trips | UDP round trips lost | TCP round trip min / median / 90 % / "
        "max, ms |", "|---|---|---|---|"]
    for host, probe in lab.get("probes", {}).items():
        rtt = probe["tcp_rtt"]
        lines.append(f"| {host} | {probe['count']} | {100 * probe['udp_round_trip_loss']:.1f} "
                     f"% | {1000 * rtt['min']:.1f} / {1000 * rtt['median']:.1f} / "
                     f"{1000 * rtt['p90']:.1f} / {1000 * rtt['max']:.1f} |")
    packets = [p for lb in labs for p in lb.get("packets", {}).values()]
    total = sum(p["total"] for p in packets)
    dropped = sum(p["dropped"] for p in packets)
    t_end = lab.get("t_end", 0.0)
    lines += ["", f"(A UDP round trip crosses the link twice: "
                  f"{100 * (1 - (1 - loss) ** 2):.2f} % expected.) Over the runs the "
                  f"loss rules of the hosts saw {total} packets and dropped "
                  f"{dropped} ({100 * dropped / max(total, 1):.2f} %).", "",
              "| run | robots | collisions | smallest clearance (certified), m | arrived "
              f"by t_end {lab.get('scenario_t_end', 0.0):g} s (largest error, m) | last "
              f"arrival, s | arrived by the end, {t_end:g} s (largest error, m) | samples | "
              "stood still (check) | shifted plans | phase shifts | plan waits | late "
              "samples | plans received | wall, s |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    lines += [_row(f, scenario, i + 1, wall, status) for i, (f, wall, status)
              in enumerate(runs)]
    lines += [
        "", f"Load average at the end (1, 5, 15 min): {load}.",
        "", f"Arrival: {why}, at the scenario's t_end and at the end of the run "
        "(`--t-end`); *last arrival*: the scenario time from which the last robot stayed "
        "within it. Counts as in the table above, added up over the controllers. Collisions "
        "and clearance on the simulated robots' true poses (exact arcs between commands, 2 "
        "ms grid, certified between grid points).", "<!-- /hosts -->"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run, print the section, write it into ``docs/ros2.md``."""
    p = argparse.ArgumentParser(prog="benchmarks.ros2_hosts",
                                description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="swap-16")
    p.add_argument("--loss", type=float, default=0.05)
    p.add_argument("--delay", type=float, default=0.02)
    p.add_argument("--t-end-factor", type=float, default=1.0, metavar="F",
                   help="run F times the scenario's t_end (arrival is reported at both)")
    p.add_argument("--lead", type=float, default=0.25, metavar="S",
                   help="the controllers' --lead, s (default 0.25)")
    p.add_argument("--repeat", type=int, default=3, metavar="N",
                   help="runs in a row, one row each (default 3)")
    p.add_argument("--no-write", action="store_true")
    args = p.parse_args(argv)
    problem = lab_problem()
    if problem:
        print(f"benchmarks.ros2_hosts: error: {problem}", file=sys.stderr)
        return 2
    tolerance, why = arrival_tolerance(args.scenario)
    runs = []
    with TemporaryDirectory(prefix="sqpmpc-ros2-hosts-") as tmp:
        t_end = args.t_end_factor * load_scenario(args.scenario).t_end
        for i in range(args.repeat):
            folder = Path(tmp) / f"run{i + 1}"
            started = time.time()
            status = hosts.main(["--scenario", args.scenario, "--loss", repr(args.loss),
                                 "--delay", repr(args.delay), "--out", str(folder),
                                 "--t-end", repr(t_end),
                                 "--tolerance", repr(tolerance), "--log-level", "INFO",
                                 "--lead", repr(args.lead)])
            runs.append((folder, time.time() - started, status))
            print(_row(folder, args.scenario, i + 1, runs[-1][1], status), flush=True)
        text = report(runs, args.scenario, args.loss, args.delay, why, args.lead)
    print(text)
    if not args.no_write:
        doc = OUT.read_text()
        old = section(doc, "hosts")
        OUT.write_text(doc.replace(old, text) if old else doc.rstrip("\n") + "\n\n" + text + "\n")
        print(f"wrote {OUT}")
    return max(status for _, _, status in runs)


if __name__ == "__main__":
    sys.exit(main())
