"""Benchmarks of the distributed services (real processes, Zenoh on loopback).

``python -m benchmarks.bench_services [--out DIR] [--repeat R] [--duration S]
[--sample-time TS] [--horizon N] [--skip-lockstep] [--skip-realtime]``

1. **Lockstep**: paper-s2 (800 samples), plant + 4 robot processes through
   ``services.launch``, without and with ``--pin-cpus``; prints the plant's
   sample-loop wall time (target <= 2.5 s), the launcher's total wall time and
   the largest state difference to the in-process run (must be <= 1e-9).
2. **Real time**: 8 robots on a circle of radius 4 m swapping to the opposite
   point, ``Ts = 0.1 s`` and ``N = 20`` (a 2 s horizon) by default, for
   ``--duration`` seconds (default 60), plant + 8 robot processes; prints the
   missed deadlines reported by the plant and whether every robot arrived.
   The horizon matters: with ``Ts = 0.05 s, N = 8`` (0.4 s, 0.24 m of travel)
   robots cannot see past each other, and swaps of 4, 6 and 8 robots jam in
   the centre, 4.3-4.8 m from their goals, in both schemes, even with longer
   detour holds. With 2 s (``N = 20`` at 0.1 s, ``N = 40`` at 0.05 s) or 4 s
   they arrive in process. On these 2 cores, 8 robots at ``Ts = 0.05 s,
   N = 40`` cannot keep up (half the inputs were fallbacks).

Prints figures only; nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import ClosedLoopSimulation

ROOT = Path(__file__).resolve().parent.parent

__all__ = ["circle_swap_toml", "main"]


def circle_swap_toml(n: int = 8, radius: float = 4.0, sample_time: float = 0.1,
                     t_end: float = 60.0, horizon: int = 20) -> str:
    """A scenario (TOML text): ``n`` robots on a circle, each going to the opposite point."""
    lines = [
        f'name = "circle-swap-{n}"', f"t_end = {t_end!r}", f"sample_time = {sample_time!r}",
        f"horizon = {horizon}", "", "[weights]", "Q = [1.0, 1.0]", "R = [0.5, 0.5]", "",
        "[bounds]", "v = [-0.6, 0.6]", f"omega = [{-math.pi / 4!r}, {math.pi / 4!r}]",
    ]
    for j in range(n):
        a = 2.0 * math.pi * j / n
        x, y = radius * math.cos(a), radius * math.sin(a)
        lines += ["", "[[robots]]", f"id = {j + 1}",
                  f"initial_state = [{x!r}, {y!r}, {a + math.pi!r}]", "diameter = 0.3",
                  f'reference = {{ type = "point", position = [{-x!r}, {-y!r}] }}']
    return "\n".join(lines) + "\n"


def _launch(out: Path, args: list[str]) -> tuple[float, dict]:
    cmd = [sys.executable, "-m", "services.launch", "--out", str(out), "--no-plots", *args]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"launcher failed ({res.returncode}):\n{res.stderr}")
    return wall, json.loads((out / "metrics.json").read_text())


def bench_lockstep(out: Path, repeat: int) -> None:
    """paper-s2 lockstep, decentralized: loop wall time and agreement with the in-process run."""
    scenario = load_scenario("paper-s2")
    t0 = time.perf_counter()
    reference = ClosedLoopSimulation(scenario, "decentralized").run()
    in_process = time.perf_counter() - t0
    print(f"in-process decentralized paper-s2 ({scenario.steps} samples): {in_process:.2f} s, "
          f"controller time {reference.solve_times.sum():.2f} s")
    for pin in (False, True):
        loops = []
        for r in range(repeat):
            run_out = out / f"lockstep-{'pinned' if pin else 'free'}-{r}"
            args = ["--scenario", "paper-s2", "--scheme", "decentralized"]
            wall, m = _launch(run_out, args + (["--pin-cpus"] if pin else []))
            states = np.load(run_out / "trajectory.npz")["states"]
            diff = float(np.max(np.abs(states - reference.states)))
            loop = m["sample_loop_wall_s"]
            loops.append(loop)
            print(f"lockstep {'pinned' if pin else 'unpinned'} run {r + 1}: sample loop "
                  f"{loop:.2f} s ({1e3 * loop / m['steps']:.2f} ms/sample), launcher total "
                  f"{wall:.2f} s, max state difference {diff:.3g}, "
                  f"missed {m['missed_deadlines']}, collisions {m['collisions']}")
        print(f"lockstep {'pinned' if pin else 'unpinned'}: median sample loop "
              f"{np.median(loops):.2f} s over {repeat} runs (target <= 2.5 s)")


def bench_realtime(out: Path, duration: float, sample_time: float, horizon: int) -> None:
    """8 robots swapping on a circle, wall-clock paced: missed deadlines and arrival."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "circle-swap-8.toml"
        path.write_text(circle_swap_toml(sample_time=sample_time, t_end=duration,
                                         horizon=horizon))
        (out / "circle-swap-8.toml").parent.mkdir(parents=True, exist_ok=True)
        (out / "circle-swap-8.toml").write_text(path.read_text())
        wall, m = _launch(out / "realtime-8", ["--scenario", str(path), "--scheme",
                                               "decentralized", "--mode", "realtime"])
    total = m["steps"] * len(m["ids"])
    missed = m["missed_deadlines"]
    st = m["solve_time"]
    print(f"realtime circle-swap-8, Ts = {m['sample_time']} s, {m['steps']} samples "
          f"({m['sample_loop_wall_s']:.1f} s wall, launcher {wall:.1f} s): missed deadlines "
          f"{missed} of {total} inputs ({100.0 * missed / total:.2f} %)"
          f", by robot {m['missed_deadlines_by_robot']}, late commands {m['late_commands']}")
    print(f"  collisions {m['collisions']} (between samples {m['intersample_collisions']}), "
          f"min clearance {m['min_clearance']:.4g} m, solver failures {m['solver_failures']}, "
          f"QP rescues {m['counters'].get('qp_rescues', 0)}, "
          f"controller time per sample (sum over robots) "
          f"median {st['median_ms']:.2f} ms, p99 {st['p99_ms']:.2f} ms, max {st['max_ms']:.2f} ms")
    err = m["max_final_position_error"]
    print(f"  horizon N = {horizon} ({horizon * m['sample_time']:.2f} s): largest final distance "
          f"to the goal {err:.3f} m ({'every robot arrived' if err <= 0.05 else 'NOT arrived'})")


def main(argv: list[str] | None = None) -> int:
    """Entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="keep the runs here")
    parser.add_argument("--repeat", type=int, default=3, help="lockstep runs per setting")
    parser.add_argument("--duration", type=float, default=60.0, help="realtime run length, s")
    parser.add_argument("--sample-time", type=float, default=0.1, help="realtime run's Ts, s")
    parser.add_argument("--horizon", type=int, default=20,
                        help="realtime run's horizon N (20 = 2 s at Ts = 0.1 s; with a 0.4 s "
                             "horizon robots cannot see past each other and the swap jams)")
    parser.add_argument("--skip-lockstep", action="store_true")
    parser.add_argument("--skip-realtime", action="store_true")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        if not args.skip_lockstep:
            bench_lockstep(out, args.repeat)
        if not args.skip_realtime:
            bench_realtime(out, args.duration, args.sample_time, args.horizon)
    return 0


if __name__ == "__main__":
    sys.exit(main())
