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

__all__ = ["CASES", "main", "render"]

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


def render(rows: list[dict]) -> str:
    """The rows as a Markdown table."""
    head = ("| run | collisions | smallest clearance (certified), m | arrived | honest arrived "
            "| last arrival, s | command timeouts (robots stopped, s) | false plans refused "
            "| named untrusted (by controllers) | attacker sent | samples | stood still "
            "| wall, s |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    out = []
    for r in rows:
        if "robots" not in r:
            out.append(f"| {r['name']} | failed (status {r['status']}) ||||||||||||")
            continue
        arrival = r.get("arrival_times", {})
        last = "-" if None in arrival.values() else f"{max(arrival.values()):.1f}"
        honest = {k: v for k, v in r["final_errors"].items()
                  if not (r["name"].startswith(("freeze", "herd", "flood")) and k == "2")}
        ok = sum(e <= r["tolerance"] for e in honest.values())
        timeouts = sum(r.get("command_timeouts", {}).values())
        stood = sum(r.get("timed_out", {}).values())
        named = ", ".join(f"robot {k} ({v})" for k, v in sorted(r["named"].items())) or "-"
        sent = ", ".join(f"{k} {v}" for k, v in r.get("forger", {}).items() if v) or "-"
        c = r["counts"]
        out.append(
            f"| {r['name']} | {r['collisions']} | {r['min_clearance']:.3f} "
            f"({r['certified_clearance']:.3f}) | {r['arrived']}/{r['robots']} | "
            f"{ok}/{len(honest)} | {last} | {timeouts} ({stood:.1f}) | "
            f"{c.get('false_plans', 0)} | {named} | {sent} | {c.get('samples', 0)} | "
            f"{c.get('brakes', 0)} | {r['wall']:.0f} |")
    return head + "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Run the rows, print the table, write its section of ``docs/ros2.md``."""
    p = argparse.ArgumentParser(prog="benchmarks.ros2_protections",
                                description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="+", choices=sorted(CASES), default=None)
    p.add_argument("--repeat", type=int, default=5, help="runs of the nominal row (default 5)")
    p.add_argument("--json", type=Path, default=None, help="also write the rows here")
    p.add_argument("--no-write", action="store_true")
    args = p.parse_args(argv)
    rows: list[dict] = []
    began = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    with TemporaryDirectory(prefix="sqpmpc-ros2p-") as tmp:
        for name in args.only or CASES:
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
        block = (f"<!-- protections -->\n`python -m benchmarks.ros2_protections` ({began}, "
                 f"this machine, 2 cores shared with other sessions):\n\n{table}"
                 "<!-- /protections -->")
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
