"""A ROS 2 fleet with every robot on a host of its own, loss and delay between hosts.

``sudo python -m benchmarks.ros2_hosts [--scenario swap-16] [--loss 0.05]
[--delay 0.02] [--no-write]`` (root: network namespaces)

One run of :mod:`services.ros2.hosts`: one network namespace per robot
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


def report(folder: Path, scenario: str, loss: float, delay: float, why: str,
           wall: float, status: int) -> str:
    """The doc section of a run whose output folder is ``folder``."""
    lab = json.loads((folder / "lab.json").read_text())
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    lines = [
        "<!-- hosts -->", "## Every robot a host of its own", "",
        f"`sudo python -m benchmarks.ros2_hosts` ({date}): `python -m services.ros2.hosts "
        f"--scenario {scenario} --loss {loss:g} --delay {delay:g}` on this machine (2 cores "
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
        "Links, measured before the fleet started (UDP datagrams echoed by the hub over "
        "the link; 64-byte TCP messages echoed through the relay):", "",
        "| host | round trips | UDP round trips lost | TCP round trip min / median / 90 % / "
        "max, ms |", "|---|---|---|---|"]
    for host, probe in lab.get("probes", {}).items():
        rtt = probe["tcp_rtt"]
        lines.append(f"| {host} | {probe['count']} | {100 * probe['udp_round_trip_loss']:.1f} "
                     f"% | {1000 * rtt['min']:.1f} / {1000 * rtt['median']:.1f} / "
                     f"{1000 * rtt['p90']:.1f} / {1000 * rtt['max']:.1f} |")
    packets = lab.get("packets", {})
    total = sum(p["total"] for p in packets.values())
    dropped = sum(p["dropped"] for p in packets.values())
    lines += ["", f"(A UDP round trip crosses the link twice: "
                  f"{100 * (1 - (1 - loss) ** 2):.2f} % expected.) Over the whole run the "
                  f"loss rules of the {len(packets)} hosts saw {total} packets and dropped "
                  f"{dropped} ({100 * dropped / max(total, 1):.2f} %)."]
    check = folder / "check.json"
    if check.exists():
        r = json.loads(check.read_text())
        c = log_counts(folder / "logs")
        cut_file = folder / "check-scenario-t_end.json"
        cut = json.loads(cut_file.read_text()) if cut_file.exists() else r
        lines += [
            "", "| run | robots | collisions | smallest clearance (certified), m | arrived "
            f"by t_end {lab['scenario_t_end']:g} s (largest error, m) | arrived by the "
            f"end, {lab['t_end']:g} s (largest error, m) | samples | stood still (check) | "
            "phase shifts | late samples | stale odometry | plans received | wall, s |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
            f"| {scenario}, {len(packets)} hosts | {r['robots']} | {r['collisions']} | "
            f"{r['min_clearance']:.3f} ({r['certified_clearance']:.3f}) | "
            f"{cut['arrived']}/{cut['robots']} ({max(cut['final_errors'].values()):.3f}) | "
            f"{r['arrived']}/{r['robots']} ({max(r['final_errors'].values()):.3f}) | "
            + " | ".join(str(c.get(k, 0)) for k in (
                "samples", "brakes", "phase_shifts", "late_samples", "stale_odometry",
                "plans_received")) + f" | {wall:.0f} |",
            "", f"Load average at the end (1, 5, 15 min): {load}.",
            "", f"Arrival: {why}; the run lasts {lab['t_end']:g} s (`--t-end`), arrival "
            f"is measured on the same run at the scenario's t_end and at the end. Counts as "
            "in the table above, added up over the controllers. Collisions and clearance on "
            "the simulated robots' true poses (exact arcs between commands, 2 ms grid, "
            "certified between grid points)."]
    else:
        lines += ["", f"The run failed (status {status}): no fleet log to check."]
    lines.append("<!-- /hosts -->")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run, print the section, write it into ``docs/ros2.md``."""
    p = argparse.ArgumentParser(prog="benchmarks.ros2_hosts",
                                description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="swap-16")
    p.add_argument("--loss", type=float, default=0.05)
    p.add_argument("--delay", type=float, default=0.02)
    p.add_argument("--t-end-factor", type=float, default=2.0, metavar="F",
                   help="run F times the scenario's t_end (arrival is reported at both)")
    p.add_argument("--no-write", action="store_true")
    args = p.parse_args(argv)
    problem = lab_problem()
    if problem:
        print(f"benchmarks.ros2_hosts: error: {problem}", file=sys.stderr)
        return 2
    tolerance, why = arrival_tolerance(args.scenario)
    with TemporaryDirectory(prefix="sqpmpc-ros2-hosts-") as tmp:
        folder = Path(tmp) / "run"
        started = time.time()
        t_end = args.t_end_factor * load_scenario(args.scenario).t_end
        status = hosts.main(["--scenario", args.scenario, "--loss", repr(args.loss),
                             "--delay", repr(args.delay), "--out", str(folder),
                             "--t-end", repr(t_end),
                             "--tolerance", repr(tolerance), "--log-level", "INFO"])
        text = report(folder, args.scenario, args.loss, args.delay, why,
                      time.time() - started, status)
    print(text)
    if not args.no_write:
        doc = OUT.read_text()
        old = section(doc, "hosts")
        OUT.write_text(doc.replace(old, text) if old else doc.rstrip("\n") + "\n\n" + text + "\n")
        print(f"wrote {OUT}")
    return status


if __name__ == "__main__":
    sys.exit(main())
