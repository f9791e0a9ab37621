"""Simulated ROS 2 fleets driven by ``sqpmpc robot --ros2`` -> ``docs/ros2.md``.

``python -m benchmarks.ros2 [--only NAME ...] [--repeat NAME:N ...] [--no-write]``

Each row is one run of :mod:`services.ros2.demo`: the simulated ROS 2 robots
(zenoh-ros2-sdk, odometry at 50 Hz with phases of their own), one controller
process per robot on its own clock with a random phase, the plans over the
sqpmpc keys with the run's credentials (mutual TLS, access control), two
Zenoh routers (ROS 2 side, sqpmpc side) on loopback. The measures are taken
on the simulated robots' true poses (:mod:`services.ros2.check`): collisions
and the smallest clearance over a 2 ms grid with its certified bound between
grid points, final distance to the reference, and, for a robot whose
odometry stops, the time from the stop to its first zero command.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from tempfile import TemporaryDirectory

from benchmarks.faults import arrival_tolerance
from services.ros2 import demo
from services.ros2.record import controller_counts

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "docs" / "ros2.md"
CASES = {
    "paper-s2": ["--scenario", "paper-s2"],
    "swap-16": ["--scenario", "swap-16"],
    "swap-16-odom-stop": ["--scenario", "swap-16", "--odom-stop", "5:8"],
}
"""Row name -> demo arguments."""

__all__ = ["CASES", "HOSTS_PENDING", "OUT", "PROTECTIONS_PENDING", "log_counts", "main",
           "run_case", "section"]

HOSTS_PENDING = """<!-- hosts -->
## Every robot a host of its own

Not run yet: `sudo python -m benchmarks.ros2_hosts` writes this section.
<!-- /hosts -->"""
"""The hosts section before :mod:`benchmarks.ros2_hosts` has run."""
PROTECTIONS_PENDING = """<!-- protections -->
## Protections

Not run yet: `python -m benchmarks.ros2_protections` writes this section.
<!-- /protections -->"""
"""The protections section before :mod:`benchmarks.ros2_protections` has run."""


def run_case(name: str, folder: Path, tolerance: float) -> dict:
    """Run one row; returns its measures (``check.json`` and the controllers' counts)."""
    started = time.time()
    status = demo.main([*CASES[name], "--out", str(folder), "--log-level", "INFO",
                        "--tolerance", repr(tolerance)])
    row = {"name": name, "status": status, "wall": time.time() - started}
    check = folder / "check.json"
    if check.exists():
        row.update(json.loads(check.read_text()))
    row["counts"] = log_counts(folder / "logs")
    return row


def log_counts(logs: Path) -> dict[str, int]:
    """Every controller's final counts (``samples``, ``brakes``, ...) added up, from the
    ``robot-*.log`` files in ``logs`` (:func:`services.ros2.record.controller_counts`)."""
    return controller_counts(logs)


def section(text: str, name: str) -> str | None:
    """The text between ``<!-- NAME -->`` and ``<!-- /NAME -->`` in ``text`` (markers
    included), if there."""
    start, end = f"<!-- {name} -->", f"<!-- /{name} -->"
    i, j = text.find(start), text.find(end)
    return text[i:j + len(end)] if 0 <= i < j else None


def _table(rows: list[dict]) -> str:
    head = ("| run | robots | collisions | smallest clearance (certified), m | arrived "
            "| largest final error, m | last arrival, s | stop to zero, s | samples | stood "
            "still (check) | shifted plans | phase shifts | plan waits | late samples | stale "
            "odometry | wall, s |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    for r in rows:
        if "robots" not in r:
            lines.append(f"| {r['name']} | failed (status {r['status']}) |||||||||||||||")
            continue
        stops = ", ".join(f"robot {k}: {v:.3f}" if v is not None else f"robot {k}: none"
                          for k, v in r["stop_to_zero"].items()) or "-"
        arrivals = r.get("arrival_times", {}).values()
        last = "-" if not arrivals or None in arrivals else f"{max(arrivals):.1f}"
        lines.append(
            f"| {r['name']} | {r['robots']} | {r['collisions']} | {r['min_clearance']:.3f} "
            f"({r['certified_clearance']:.3f}) | {r['arrived']}/{r['robots']} | "
            f"{max(r['final_errors'].values()):.3f} | {last} | {stops} | "
            + " | ".join(str(r["counts"].get(key, 0)) for key in (
                "samples", "brakes", "shifted_plans", "phase_shifts", "plan_waits",
                "late_samples", "stale_odometry"))
            + f" | {r['wall']:.0f} |")
    return head + "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Run the rows, print the table, write ``docs/ros2.md``."""
    p = argparse.ArgumentParser(prog="benchmarks.ros2", description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="+", choices=sorted(CASES), default=None)
    p.add_argument("--repeat", nargs="+", default=["swap-16:3"], metavar="NAME:N",
                   help="run row NAME N times in a row, rows 'NAME #i' (default swap-16:3)")
    p.add_argument("--no-write", action="store_true")
    args = p.parse_args(argv)
    repeat = {}
    for item in args.repeat:
        name, _, n = item.partition(":")
        if name not in CASES or not n.isdigit() or int(n) < 1:
            p.error(f"--repeat: expected NAME:N with NAME one of {', '.join(CASES)} and N >= "
                    f"1, got {item!r}")
        repeat[name] = int(n)
    rows, criteria = [], {}
    with TemporaryDirectory(prefix="sqpmpc-ros2-") as tmp:
        for name in args.only or CASES:
            scenario = CASES[name][1]
            if scenario not in criteria:
                criteria[scenario] = arrival_tolerance(scenario)
            runs = repeat.get(name, 1)
            for i in range(runs):
                label = name if runs == 1 else f"{name} #{i + 1}"
                rows.append(run_case(name, Path(tmp) / f"{name}-{i + 1}",
                                     criteria[scenario][0]))
                rows[-1]["name"] = label
                print(_table(rows[-1:]), flush=True)
    table = _table(rows) + "\nArrival: " + "; ".join(
        f"{name}: {why}" for name, (_, why) in criteria.items()) + ".\n"
    print(table)
    if not args.no_write:
        hosts = section(OUT.read_text(), "hosts") if OUT.exists() else None
        protections = section(OUT.read_text(), "protections") if OUT.exists() else None
        OUT.write_text(_DOC.format(table=table, hosts=hosts or HOSTS_PENDING,
                                   protections=protections or PROTECTIONS_PENDING,
                                   date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())))
        print(f"wrote {OUT}")
    return 0 if all(r.get("collisions", 1) == 0 for r in rows) else 1


_DOC = """# ROS 2 robots over Zenoh

`sqpmpc robot --id ID --scenario S --ros2` drives a ROS 2 robot (CONTRACT 4):
`nav_msgs/Odometry` in on `NS/odom`, `geometry_msgs/Twist` (or `TwistStamped`,
`--twist-stamped`) out on `NS/cmd_vel` (each sample's input, republished at `--cmd-rate`,
default 20 Hz), its plan as `nav_msgs/Path` on
`NS/plan`, in rmw_zenoh's key format, CDR, attachments and graph tokens
(`services.ros2`). There is no plant process: each robot runs on its own clock at
the scenario's `Ts` with a phase of its own, takes its own state from its odometry and
its neighbours' states from their time-stamped plans, exchanged over the sqpmpc keys
with the run's credentials.

## The wire format

`services/ros2/msgs.py` and `services/ros2/graph.py` are the project's own encoder of
rmw_zenoh's format (ROS 2 Jazzy): data keys `<domain>/<topic>/<pkg>::msg::dds_::<Type>_/
RIHS01_<hash>`, the type hashes computed from the message definitions (REP 2011),
CDR little endian with its 4-byte header, the 33-byte attachment (sequence number from 1,
source timestamp in ns, GID length 16 and the GID), liveliness tokens `@ros2_lv/<domain>/
<zid>/<node id>/<entity id>/<NN|MP|MS>/%/<namespace>/<node>[/<topic>/<type>/<hash>/<qos>]`.
`tests/test_ros2_wire.py` checks them against two independent implementations from
the registry: zenoh-ros2-sdk (keys, type hashes, tokens, QoS strings, attachments) and
rosbags (CDR bytes of Twist, TwistStamped, Odometry and Path for random values, and type
hashes); over a router on loopback zenoh-ros2-sdk subscribers receive the encoder's
TwistStamped and Path, the encoder's node receives the SDK's Odometry, and the SDK's graph
query lists the node and its topics. `tests/test_ros2_fleet.py` runs three robots as
processes (simulated with zenoh-ros2-sdk) and watches one controller's `cmd_vel` and
`plan` with zenoh-ros2-sdk.

## How a robot stays safe without a common clock

No two robots sample at the same instants, so no pair can build a shared row from the
same two plans. What a robot does know: a neighbour applies each plan's first input from
the plan's stamp for one sample, so that arc is exact. Each sample, at `T_k - lead`, the
robot plans with every neighbour as a moving obstacle (its exact arcs, then standing
where they end) and then checks the first input along the exact arc of the whole sample
(100 points, the distance change between points added): every required distance plus
`--ros2-margin` from all of each neighbour's arc since the start of its current sample (a
robot may stop at any moment: its odometry lost, shut down), and after that arc from

- a neighbour that decides its next input after this check: where its arc ends
  (when it decides it has this robot's new plan and avoids it, or has an
  older one and keeps out of everywhere this robot may reach);
- a neighbour that decided before this check but whose plan is not here yet (or was
  lost): the disc it may reach since;
- a neighbour that left: where it stopped, plus a sample's reach.

The check is the controller's own first-input check
(`services.ros2.controller.Ros2Controller.first_input_safe`), so a refused input is
handled as in lockstep: the shifted plan of the previous sample if its first input passes
the same check, else the robot stands still, which is always safe: whoever decides later
avoids it, whoever decided earlier kept out of all of its arc and where it ends, or of
all it could reach. As the controller knows what the robot applied, the liveness rules
work as in lockstep: `detour`, `stall-repair` and `gear-cycle` read the applied inputs,
`roundabout` the neighbours' headings (taken from their plans' arcs). Before (up to
6384a41) the check ran after the controller's step: a refused input was still taken
as applied, so `detour` never saw a held robot as standing, and every neighbour's
heading read 0, so `roundabout` took every neighbour as traffic for a robot heading
east and as a crowd for one heading west; the swap's centre jammed (14/16 on loopback;
10/16 by t_end in two of four runs on the hosts, 482 refused inputs, 478 phase shifts).

A robot about to compute its sample waits while a neighbour within reach that decides
before it (its next instant in the sample before this robot's) has not delivered that
plan yet (at most until twice its recent step time before its instant;
`Neighbours.awaited`): the check then has the neighbour's exact arc instead of the disc
it may reach, and a pair decides in the order of its instants. Only the later robot of a
pair waits, so two never wait for each other. Deciding later than `T_k - lead` is safe:
a neighbour deciding in between has this robot's previous plan, whose next decision it
sees as past, so it keeps out of all this robot may reach.

A robot held by a neighbour deciding at about its own instants moves its instants by
0.2-0.4 Ts (a phase shift; only while it stands) and announces it at once: a plan
standing where it is, stamped a sample before its new instant (true: it commands zero
until then). Without it the neighbours expected its next plan a sample after the last,
took the shifted one for a plan in flight, held the robot by the disc it may reach and
were refused in turn, and shifted too: on the hosts (plans 40 ms and TCP resends on
their way) refusals and phase shifts fed each other, 582 refused inputs and 577 phase
shifts in a run that ended 5/16. (An earlier version took a
neighbour's arc as certain to be followed to its end; in its odometry-stop run a robot
that stopped inside its sample was hit, clearance -0.025 m. The check now covers a stop
at any moment.)
So at every instant the robot of a pair that decided last kept the distance from what
the other does. The assumptions: every robot follows its published arc (odometry and
command latency within the margins), the fleet shares `--lead`, clocks agree within
`--ros2-guard` (0.02 s). A robot whose odometry is older than `--odom-timeout` (0.6 Ts)
commands zero at once (checked between samples too) and publishes a plan standing where
the odometry and its commands put it; the others keep their distance from it.

## Acceleration limits

With the scenario's `[bounds]` `acceleration` and `angular_acceleration` (CONTRACT 1c)
the simulated robots' velocity controllers move each velocity toward the command at
`clip((command - v) / Ts, lower, upper)` (the plant's rule: the command reached within a
sample when the limits allow), updated every 5 ms (`--control-rate`), and the odometry
reports the velocities the robot has. The controller gets `(robots, 5)` states: its own
pose and `(v, omega)` from the newest odometry carried forward with the commands sent
since, ramping under the same rule (`services.ros2.timing.own_motion`). The check of each
input takes a command as followed at once on its arc; under acceleration limits its
margin also holds the ramp's distance from that arc (`model_margin` over the velocity and
acceleration boxes, for the pair) and the braking distance `v^2 / (2 |a|)` of a robot told
to stop (`services.ros2.options.check_margin`). `tests/test_ros2_limits.py` checks the
ramp and the carried-forward state against the simulated robot; `tests/test_ros2_fleet.py`
runs two robots with limits: no velocity step above the limit times the update period,
no collision, both arrive. The margins are large at `Ts` = 0.5 s (0.49 m for 0.5 m/s and
1 m/s^2: 0.36 m of ramp deviation, 0.125 m of braking); inside it the check accepts a path
that gets no closer than the robot is now, so a robot that used up its braking distance can
leave. Not solved: in a crossing of two such robots both can stand still for good near
each other (before the check moved into the controller: 3 of 9 runs of a symmetric
crossing, 2 of 6 with one robot 2 s later; after (db837b9), with the liveness rules
seeing the robots stand: 2 of 3 runs of the symmetric crossing, both robots 1.84 m before their
goals and 0.73 m apart, inside the 0.79 m the check keeps, where every `detour` target
lies closer to the other; 0 collisions in all).

## Runs

`python -m benchmarks.ros2` ({date}): `sqpmpc launch --ros2-demo` per row, on this
machine (2 cores shared by every process), measures on the simulated robots' true
poses (exact arcs between commands, checked on a 2 ms grid; the certified clearance
bounds every instant in between).

{table}
*Last arrival*: the scenario time from which the last robot stayed within the
tolerance (`services.ros2.check`). The counts add up every controller's: *samples*
computed, *stood still* (the check refused the QP's input and the shifted plan's),
*shifted plans* (it refused the QP's input and passed the shifted plan's), *phase
shifts* (a robot held by a neighbour deciding at about the same instants moved its own
instants by 0.2-0.4 Ts, announced; only while standing), *plan waits* (samples in which the robot
waited for a plan in flight), *late samples* (a plan not ready before its instant: the
robot stood still), *stale odometry* (times a controller found its odometry older than
`--odom-timeout` and commanded zero). A robot whose odometry stops cannot arrive:
arrival counts it as not arrived.

{hosts}

Runs of the swap-16 on the hosts on the way (2026-11-24, 0 collisions in every one):
with the check inside the controller and the awaited plans, before merging main's
roundabout rings, at the default `--lead` (0.15 s; 07:14-07:22, load average 9-16):
16/16 by t_end (last arrival 41.1 s), 14/16 (2.474 m), 12/16 (5.914 m), refused
inputs 101, 208, 328, phase shifts 106, 205, 345; at `--lead 0.25` (a step and a plan's
40 ms between hosts fit in it; 07:25-07:34): 16/16 (47.4 s), 16/16 (39.7 s), 5/16
(6.139 m), refused 125, 185, 582, phase shifts 136, 189, 577. After merging main,
without the announced phase shifts: 8/16 (5.709 m), 580 refused, 618 phase shifts
(07:38); with them: 16/16 (32.9 s), 42 refused, 47 phase shifts (07:42), then the three
runs of the table. The hosts benchmark runs at `--lead 0.25`. On loopback, the same tree
before main's merge (07:08-07:13): swap-16 16/16 three times (last arrivals 34.9, 35.0,
35.9 s; refused 57, 13, 14; phase shifts 54, 10, 11), odometry stop 15/16 (robot 5).

The loopback table's swap-16 and odometry-stop rows are of the final tree; its
paper-s2 row is of the tree before main's merge and the announced phase shifts
(07:00-07:07): 4 robots rarely wait or shift (1 refused input, 1 phase shift). Load
averages while the loopback rows ran: 3.8 at their start, 9-16 by their end (other
sessions share the machine).

The tree before (6384a41) on the same machine: loopback swap-16 14/16 (05:08; 16/16 at
02:37 and 04:28), 181 refused inputs, 172 phase shifts; hosts 16/16 by t_end in two of
four runs, 10/16 in the other two (all 16 by 98 s), 482 refused inputs and 478 phase
shifts in one run; 0 collisions in every run.

{protections}
"""

if __name__ == "__main__":
    sys.exit(main())
