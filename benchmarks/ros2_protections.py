"""The ROS 2 mode's protections, measured on simulated ROS 2 fleets -> ``docs/ros2.md``.

``python -m benchmarks.ros2_protections [--only NAME ...] [--repeat N] [--no-write]``

Each row is one run of :mod:`services.ros2.demo` on swap-16 (simulated ROS 2
robots whose bases stop on a 0.5 s command timeout, as ROS 2 Jazzy's
diff_drive_controller; the plans with the run's credentials, mutual TLS and
access control), measured on the robots' true poses (:mod:`services.ros2.check`):

- ``once-per-sample``: cmd_vel sent once per sample (``--cmd-rate 0``), as
  before the command stream;
- ``nominal``: the defaults (cmd_vel republished at 20 Hz), ``--repeat`` times;
- ``freeze``, ``herd``: a :mod:`services.forger` holding robot 2's own key sends,
  for every plan of a neighbour, a plan of robot 2 stamped at that neighbour's
  next instant, standing where it will be (``freeze``) or 0.35 m ahead of it
  (``herd``); robot 2's own controller runs as well;
- ``flood``: the forger re-sends robot 2's plan and command as fast as it can
  (nice 0, the same two cores);
- ``kill``: robot 5's controller killed (SIGKILL) at t = 12 s, amid the swap,
  started again 3 s later (credentials handed over anew).

The section between ``<!-- protections -->`` markers of ``docs/ros2.md`` is replaced.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path
from tempfile import TemporaryDirectory

from benchmarks.ros2 import log_counts
from services.ros2 import demo

__all__ = ["ATTACKED", "CASES", "SECTION", "main", "misses", "render"]

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "docs" / "ros2.md"
BASE = ["--scenario", "swap-16"]
CASES = {
    "once-per-sample": [*BASE, "--cmd-rate", "0"],
    "nominal": BASE,
    "freeze": [*BASE, "--attack", "freeze:2"],
    "herd": [*BASE, "--attack", "herd:2"],
    "flood": [*BASE, "--attack", "flood:2"],
    "kill": [*BASE, "--kill", "5:12:3"],
}
"""Row name -> demo arguments."""
ATTACKED = ("freeze", "herd", "flood")
"""Rows whose forger holds robot 2's key (robot 2 left out of *honest*)."""


SECTION = """<!-- protections -->
## Protections: real robots, real attackers (issue 31)

**A steady command stream.** A base's velocity controller stops the robot when no command
came for its timeout: `cmd_vel_timeout`, 0.5 s by default in ROS 2 Jazzy's
diff_drive_controller, exactly one sample at `Ts` = 0.5 s. `sqpmpc robot --ros2` publishes
each command at once and again every `1 / --cmd-rate` s (default 20 Hz) until the next
(`services.ros2.stream`): the sample's input, or zero when the odometry is stale, when the
plan exchange has lost its last link (a watchdog looks every 0.1 s) and at the end (given
50 ms to leave before the session closes). The simulated bases (`services.ros2.simfleet`)
stop on `--cmd-timeout` (default 0.5 s) as diff_drive_controller does and count it; a
timeout judged while the commands were only late in the simulator itself (the next one's
source timestamp within the timeout of the one before) is taken back and counted apart.

**Plans are claims, checked** (`services.ros2.neighbours.Neighbours.add`). A neighbour's
plan is kept only if its stamp is at least 0.2 Ts after the neighbour's previous plan and at
most a sample (plus `--ros2-guard`) ahead of this robot's clock, if it is the only moving
plan of its sample, if its inputs lie within the velocity bounds (1 % of the range for the
QP's tolerance) and no stage is further than `v_max Ts` from the one before, if it starts
within `--plan-tolerance` (0.05 m) plus the check's margin of where the neighbour's kept
plans put it at some moment of the sample before its stamp (a robot may stop at any moment),
and if it does not put the neighbour inside this robot: a stage 0 nearer than the required
distance less the tolerance to where this robot's own plans had it at that stamp is refused
(two robots cannot stand in one place). A plan that contradicts the newest plans of a chain
but follows the same chain without its newest plans is kept as a *fork* (a standing plan
only if that keeps a plan stamped at most 2 Ts, plus the guard, before it: one lost plan
between them; a moving one from any plan kept, within its reach): of two claims that cannot
both be true the neighbour may be on either, and the check keeps out of every claim (without
forks, a key holder's claim that robot 2 had stopped at its start, consistent with its first
plan, made every later plan of robot 2 look false: robot 2 was believed standing while it
drove on, and a flood run (below, before forks) ended in a collision of robots 1 and 2,
-0.069 m; forks and the 0.2 Ts spacing came after it). A plan with the stamp of a kept one
is a repeat only if it is the same plan or a stop where that one starts; any other is a
second claim of that instant (a fork): a key holder knows a robot's next instant, and a
forged plan stamped there that came first used to hide the robot's own. Every other plan is
refused and never kept, and nothing is added for it: where a robot may be is what its kept
claims say (exact arcs within each plan's first sample, its reach `v_max` times the time
since after them), untrusted or not. A robot whose plan is refused or forks is named in the
log (`robot 2 is untrusted from now on: its plan ...`; at the end `untrusted robot 2: N
false plans refused`).

*Why it is safe.* The check keeps out of every kept claim, so it needs only that the robot's
true plans are kept. A true plan follows the true plan before it (it starts on that one's
arc, or within the reach of a gap when plans were lost): if nothing was appended after that
one, it continues its chain; if forged plans were appended since, it follows that chain
without them, whose newest plan is the true one before (1 Ts back, 2 Ts with one plan lost
between), and is kept as a fork (the chains searched are the kept one and every fork: a
forged plan appended to the fork that holds the true path no longer makes the next true plan
unplaceable). A moving plan may fork from any plan kept within its reach: a robot whose base
did not do as its plans said (it drove on while its odometry was stale, in a machine stall:
the `kill` row below, 0.3 m off its last arc) goes on from where it truly is; standing, it
is placed again by its chain's reach within a sample. A true plan never puts its robot
inside this one: whichever of the two decided last checked its whole arc against all the
other may be doing at each instant (a stop anywhere on its arc included), so at the stamp
the two are at least the required distance plus the margin apart, within the odometry's
error (the tolerance). What is refused is therefore never a true plan, except a standing one
when the two true plans before it were both lost and a forged plan that follows the chain
came in between, or after its base did not do as its plans said (placed again within a
sample, as above), or when four forks newer than the true one crowd it out (4 kept per
robot, the newest; not proved safe, as before). The sample's reach `v_max Ts` that used to
be added for ten samples after each false plan covered neither case (a robot moves that far
in one sample) and nothing else (the kept claims place the robot); it is gone. *Before* (the
`freeze`/`herd` rows of the first table), a fork could branch from any of the 16 plans kept
(8 s), whose reach since is metres (up to 4.5 m): a forged plan standing where a neighbour
would be, anywhere within it, was kept as a fork, the neighbour stood still (it kept out of
its own next position) and the forger restated the claim at the same place every sample; and
the 0.3 m more held for good, as the forger sent a false plan every sample. *Still open:* a
key holder can still make a robot stand within a sample's reach of its plans of the last two
samples, and, with moving plans, place it anywhere within the reach of its plans kept (as
before), then keep such a fork alive by continuing it at up to `v_max` (a ghost of the robot
walking where it likes): keeping out of it is safe, but a ghost standing on a corridor or a
goal stops who needs it, as a robot standing there would; that the fleet is never stopped by
such an adaptive attacker is not shown (not measured). Plant mode does the same with the
plant's states (`services.plans.PlanStore`): a neighbour's plan must start at the plant's
state of its sample, else it is refused, the controller predicts that neighbour from its
states for that sample (the paper's fallback) and the robot is named.

**Same protections in every mode.** Every service now defaults to `--priority auto`, raised
when a real-time sample loop starts (never in lockstep), hand-started ones and `sqpmpc robot
--ros2` too; `--priority off` opts out. The per-publisher rate limit (`services.limits`,
`--max-rate`) is not on by default in any hand-started service: it is fixed when the Zenoh
session opens, when a robot cannot tell a lockstep run (whose rate is the machine's) from a
real-time one, and in the ROS 2 mode, where every plan comes through a router, Zenoh keeps
its state per link, so it limits a key, not a publisher: with it on by default (the rows
`nominal` to `kill` below), a flood on robot 2's key made every receiver drop robot 2's own
plans with the forged ones, and robot 2's neighbours collided with it (`flood`).

**Secure by default.** `sqpmpc robot` refuses to start without `--credentials`,
`--credentials-fd` or `--zenoh-config` (one error line), unless `--insecure` is given, which
it logs as `INSECURE`; the launchers pass `--insecure` to their robots only when they run
insecure themselves. The ROS 2 session takes `--ros2-zenoh-config FILE` (its connect
endpoints unless `--ros2-connect` is given), so a controller can join an rmw_zenoh network
secured with mutual TLS and access control. With ROS 2's own tools (not installable on
this machine, so not run here): `ros2 security create_keystore KEYS`, `ros2 security
create_enclave KEYS /robot1/sqpmpc_robot1` (one enclave per node), a policy (`ros2
security generate_policy policy.xml` from a running graph, or written by hand: robot N's
controller publishes `/robotN/cmd_vel` and `/robotN/plan` and subscribes to `/robotN/odom`,
its base the reverse), then `ros2 run zenoh_security_tools generate_configs -p policy.xml
-r router_config.json5 -c session_config.json5 -d 0` writes the router's and each
enclave's session config; start `rmw_zenohd` with the router's
(`ZENOH_ROUTER_CONFIG_URI`) and each controller with `--ros2-zenoh-config` its session's.
`python -m services.ros2.secure --scenario S --out DIR` writes the equivalent configs for
an sqpmpc fleet (a CA, `ros2-router.json5` with default-deny access control by certificate
common name, `controller-<id>.json5`, `base-<id>.json5`, `bases.json5`).
`tests/test_ros2_secure.py` runs the router in TLS mode with them: a controller and its
base exchange cmd_vel and odometry; robot 2's controller injecting cmd_vel into robot 1 and
spoofing its odometry gets nothing through, nor does a process without a certificate
(no link at all). An odometry stamped more than `--odom-future` (0.05 s) after its arrival
is refused and counted (`odometry_future`): one such message used to be taken as the newest
until its stamp.

**Faults.** A neighbour that left stands within a sample's reach of where its last plan put
it (its base stops on its command timeout); a robot already inside that disc may leave it
along a path on which its distance to every point of the disc never decreases (the check
accepts it). `sqpmpc launch` starts a controller killed by SIGKILL or a crash again at once,
with its credentials handed over anew (at most 3 times); `services.ros2.demo --kill
ID:T[:R]` kills a controller at `t = T` and starts it again `R` s later (default 3) with
new credentials over a new socket.

`python -m benchmarks.ros2_protections` ({date}; swap-16, 16 simulated ROS 2 robots whose
bases stop on a 0.5 s command timeout; plans with credentials, mutual TLS and access
control; this machine, 2 cores shared with other sessions). *Honest arrived*: robot 2 left
out in the attack rows; *command timeouts*: times a base stopped on its timeout while its
command was not zero and no command had been sent for the timeout (and the seconds it stood
on them; *lagged*: timeouts the simulated fleet judged while the commands were on their way,
its own lag, taken back); *false plans refused*: added up
over the controllers; *named untrusted*: the robots named, with how many controllers named
them; *attacker sent*: the forger's plans.

{table}
Rows: `once-per-sample`: `--cmd-rate 0` (cmd_vel once per sample, as before);
`nominal`: the defaults; `freeze`/`herd`: a `services.forger` with robot 2's own key sends,
for every plan of a neighbour, a plan of robot 2 stamped at that neighbour's next instant
standing where the neighbour will be (`freeze`) or 0.35 m ahead of it (`herd`), robot 2's
own controller running too; `flood`: the forger re-sends robot 2's plan and command as fast
as it can (nice 0, same cores); `kill`: robot 5's controller killed (SIGKILL) at `t` = 12 s,
started again 3 s later; `..., before forks`: the same attacks on the tree before forks
and the 0.2 Ts spacing; `40 Hz limit`: with the per-key rate limit `--max-rate 20/Ts` that
was the ROS 2 mode's default then (every row but `flood, no limit` ran with it).
{notes}<!-- /protections -->"""
"""The section of ``docs/ros2.md`` (``date``, ``table``, ``notes``)."""


def run_case(name: str, folder: Path) -> dict:
    """One row: ``check.json``, the controllers' counts and who was named untrusted."""
    started = time.time()
    status = demo.main([*CASES[name], "--out", str(folder), "--log-level", "INFO"])
    row: dict = {"name": name, "status": status, "wall": time.time() - started}
    check = folder / "check.json"
    if check.exists():
        row.update(json.loads(check.read_text()))
    logs = folder / "logs"
    row["counts"] = log_counts(logs)
    honest = Path(folder) / "honest-logs"  # the controllers but the attacked robot's
    honest.mkdir(exist_ok=True)
    for log in logs.glob("robot-*.log"):
        if not (name in ATTACKED and log.name.startswith("robot-2.")):
            (honest / log.name).write_bytes(log.read_bytes())
    row["honest_counts"] = log_counts(honest)
    named: dict[str, int] = {}
    for log in logs.glob("robot-*.log"):
        for m in re.finditer(r"untrusted robot (\d+): (\d+) false plans",
                             log.read_text(errors="replace")):
            named[m.group(1)] = named.get(m.group(1), 0) + 1
    row["named"] = named  # untrusted robot -> controllers that named it
    forger = logs / "forger.log"
    if forger.exists():
        lines = [ln for ln in forger.read_text(errors="replace").splitlines()
                 if ln.startswith("{") and '"sent"' in ln]
        row["forger"] = json.loads(lines[-1])["sent"] if lines else {}
    return row


def misses(row: dict) -> str:
    """The honest controllers' missed deadlines: samples computed late (standing plan sent),
    stopped late (no command by the instant) and skipped (overran), of all their instants;
    ``-`` for a row measured before they were counted."""
    c = row.get("honest_counts")
    if c is None or "skipped_samples" not in c:
        return "-"
    missed = c.get("late_samples", 0) + c.get("stopped_late", 0) + c["skipped_samples"]
    instants = c.get("samples", 0) + c["skipped_samples"]
    return f"{missed}/{instants} ({100.0 * missed / max(instants, 1):.1f} %)"


def render(rows: list[dict]) -> str:
    """The rows as a Markdown table."""
    head = ("| run | collisions | smallest clearance (certified), m | arrived | honest arrived "
            "| last arrival, s | command timeouts (robots stopped, s) | false plans refused "
            "| named untrusted (by controllers) | attacker sent | samples | stood still "
            "| honest deadline misses | wall, s |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    out = []
    for r in rows:
        if "robots" not in r:
            out.append(f"| {r['name']} | failed (status {r['status']}) |||||||||||||")
            continue
        arrival = r.get("arrival_times", {})
        last = "-" if None in arrival.values() else f"{max(arrival.values()):.1f}"
        honest = {k: v for k, v in r["final_errors"].items()
                  if not (r["name"].startswith(ATTACKED) and k == "2")}
        ok = sum(e <= r["tolerance"] for e in honest.values())
        timeouts = sum(r.get("command_timeouts", {}).values())
        stood = sum(r.get("timed_out", {}).values())
        lagged = sum(r.get("lagged_timeouts", {}).values())
        lag = f"; {lagged} lagged" if lagged else ""
        named = ", ".join(f"robot {k} ({v})" for k, v in sorted(r["named"].items())) or "-"
        sent = ", ".join(f"{k} {v}" for k, v in r.get("forger", {}).items() if v) or "-"
        c = r["counts"]
        out.append(
            f"| {r['name']} | {r['collisions']} | {r['min_clearance']:.3f} "
            f"({r['certified_clearance']:.3f}) | {r['arrived']}/{r['robots']} | "
            f"{ok}/{len(honest)} | {last} | {timeouts} ({stood:.1f}{lag}) | "
            f"{c.get('false_plans', 0)} | {named} | {sent} | {c.get('samples', 0)} | "
            f"{c.get('brakes', 0)} | {misses(r)} | {r['wall']:.0f} |")
    return head + "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Run the rows, print the table, write its section of ``docs/ros2.md``."""
    p = argparse.ArgumentParser(prog="benchmarks.ros2_protections",
                                description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="+", choices=sorted(CASES), default=None)
    p.add_argument("--repeat", type=int, default=5, help="runs of the nominal row (default 5)")
    p.add_argument("--json", type=Path, default=None, help="also write the rows here")
    p.add_argument("--no-write", action="store_true")
    p.add_argument("--from-json", type=Path, default=None, metavar="FILE",
                   help="render the rows a --json run wrote instead of running")
    p.add_argument("--date", default=None, help="with --from-json: when they ran")
    p.add_argument("--keep", type=Path, default=None, metavar="DIR",
                   help="keep each run's folder (logs, check.json) under DIR")
    p.add_argument("--notes", type=Path, default=None, metavar="FILE",
                   help="Markdown to put after the table (what the rows showed)")
    args = p.parse_args(argv)
    rows: list[dict] = []
    began = args.date or time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    if args.from_json is not None:
        rows = json.loads(args.from_json.read_text())
    with TemporaryDirectory(prefix="sqpmpc-ros2p-") as scratch:
        tmp = scratch if args.keep is None else str(args.keep)
        for name in [] if args.from_json is not None else args.only or CASES:
            runs = args.repeat if name == "nominal" else 1
            for i in range(runs):
                rows.append(run_case(name, Path(tmp) / f"{name}-{i + 1}"))
                if runs > 1:
                    rows[-1]["name"] = f"{name} #{i + 1}"
                print(render(rows[-1:]), flush=True)
                if args.json is not None:
                    args.json.write_text(json.dumps(rows, indent=1))
    table = render(rows)
    print(table)
    if not args.no_write and OUT.exists():
        text = OUT.read_text()
        notes = "" if args.notes is None else "\n" + args.notes.read_text().strip() + "\n"
        block = SECTION.format(date=began, table=table, notes=notes)
        start, end = text.find("<!-- protections -->"), text.find("<!-- /protections -->")
        if 0 <= start < end:
            text = text[:start] + block + text[end + len("<!-- /protections -->"):]
        else:
            text = text.rstrip("\n") + "\n\n" + block + "\n"
        OUT.write_text(text)
        print(f"wrote {OUT}")
    return 0 if all(r.get("collisions", 1) == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
