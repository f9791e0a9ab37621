"""What a run tells its user while it runs and at its end.

:class:`StatusLines`: one plain line every ``period`` seconds on a stream
(``sample 120/800 (15 %), 15 s, min clearance 0.012 m``), never a carriage
return: ``sqpmpc run`` writes them when stderr is not a terminal (a terminal
gets a progress bar), the plant service always (the launcher passes them on).
:func:`describe_solve_time`: the controller time of a run's metrics, saying
what each figure is (per robot or summed over the robots).
:func:`summarize`: the end-of-run summary of any run (in-process or
distributed), a few lines whatever the fleet's size: safety, arrival (how many
arrived, which did not), tracking and controller time, every number with three
significant digits and its unit (:func:`quantity`). :func:`missed_goal`: why a
run did not reach its goal (``--fail-on-miss``).
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

import numpy as np

from sqpmpc.io.metrics import ARRIVAL_TOLERANCE, pair_distances
from sqpmpc.problem.scenario import Scenario

__all__ = ["ARRIVAL_TOLERANCE", "STATUS_PERIOD", "StatusLines", "describe_solve_time",
           "id_ranges", "missed_goal", "quantity", "summarize"]

STATUS_PERIOD = 10.0
"""Seconds between two status lines by default."""
WORST = 5
"""How many robots a summary names at most per list (the worst first)."""


def quantity(value: Any, unit: str = "") -> str:
    """``value`` with three significant digits and its unit (``"n/a"`` when missing).

    >>> quantity(0.0009974591290105583, "m")
    '0.000997 m'
    """
    if value is None:
        return "n/a"
    text = f"{float(value):.3g}"
    return f"{text} {unit}" if unit else text


class StatusLines:
    """Periodic plain status lines of a closed loop.

    Parameters
    ----------
    scenario
        The run's scenario (samples, robot distances).
    label
        Start of every line, e.g. ``"plant"``.
    period
        Seconds between two lines (``<= 0``: none).
    stream
        Where to write (default: ``sys.stderr`` at write time).
    """

    def __init__(self, scenario: Scenario, label: str, period: float = STATUS_PERIOD,
                 stream: TextIO | None = None) -> None:
        self.total = scenario.steps
        self.label = label
        self.period = float(period)
        self.stream = stream
        self.start = time.monotonic()
        self.last = self.start
        self.lines = 0
        self.pairs = scenario.pairs()
        required = scenario.required_distances()
        self.required = required[self.pairs[:, 0], self.pairs[:, 1]] if self.pairs.size else None
        self.min_clearance = np.inf

    def update(self, k: int, states: np.ndarray, extra: str = "") -> None:
        """``k`` samples done, ``states`` ``(n, 3)`` the newest; writes a line when due."""
        if self.required is not None:
            d = pair_distances(states[None, :, :2], self.pairs)[0] - self.required
            self.min_clearance = min(self.min_clearance, float(d.min()))
        now = time.monotonic()
        if self.period > 0 and now - self.last >= self.period:
            self.last = now
            self.write(k, extra)

    def write(self, k: int, extra: str = "") -> None:
        """Write one status line now."""
        clearance = ("" if not np.isfinite(self.min_clearance)
                     else f", min clearance {quantity(self.min_clearance, 'm')}")
        self.note(f"sample {k}/{self.total} ({100.0 * k / max(self.total, 1):.0f} %), "
                  f"{time.monotonic() - self.start:.0f} s{clearance}{extra}")

    def note(self, text: str) -> None:
        """Write ``label: text`` as a line now."""
        line = f"{self.label}: {text}"
        stream = self.stream or sys.stderr
        stream.write(line.replace("\r", " ") + "\n")
        stream.flush()
        self.lines += 1


def describe_solve_time(metrics: dict[str, Any]) -> str:
    """The controller time of a run's metrics, per robot and summed, in words.

    Decentralized (one controller per robot): ``controller time per sample summed over
    the 4 robots: median 3.4 ms (max 9.1 ms); per robot: median of the robots'
    medians 0.85 ms, slowest robot 0.9 ms``. Centralized: ``controller time per
    sample (one central controller): median 2.1 ms (max 5.0 ms)``.

    With the CPU times in the metrics (``solve_time["cpu"]``) the figures are CPU
    time (thread time), the wall time's median beside them, and the load
    average at the run's end: ``controller CPU time per sample (one central
    controller): median 2.1 ms (max 5.0 ms); wall time median 2.3 ms; load
    average 1.02 on 2 CPUs``. A run whose metrics say where its controller time is
    instead (``solve_time_source``): that.
    """
    if metrics.get("solve_time_source"):  # a runner that does not see the controllers' time
        return f"controller time per sample: not measured here ({metrics['solve_time_source']})"
    wall = metrics.get("solve_time") or {}
    cpu = wall.get("cpu")
    st = cpu or wall
    controllers = int(wall.get("controllers", 1) or 1)
    clock = "controller CPU time" if cpu else "controller time"

    def ms(value: Any) -> str:
        return quantity(value, "ms")

    beside = ""
    if cpu:
        beside = f"; wall time median {ms(wall.get('median_ms'))}"
        load = wall.get("load_average")
        if load and load[0] is not None:
            cpus = wall.get("cpus")
            beside += f"; load average {load[0]:.2f}" + (f" on {cpus} CPUs" if cpus else "")
    if controllers <= 1:
        return (f"{clock} per sample (one central controller): median "
                f"{ms(st.get('median_ms'))} (max {ms(st.get('max_ms'))}){beside}")
    per_robot = [v for v in (st.get("per_robot_median_ms") or {}).values() if v is not None]
    robots = (f"; per robot: median {ms(float(np.median(per_robot)))}, slowest robot's median "
              f"{ms(max(per_robot))}" if per_robot else "")
    return (f"{clock} per sample summed over the {controllers} robots: median "
            f"{ms(st.get('median_ms'))} (max {ms(st.get('max_ms'))}){robots}{beside}")


def id_ranges(ids: list[int]) -> str:
    """Robot ids compactly, runs of consecutive ids as ranges: ``1-3, 7, 9-12``."""
    out: list[str] = []
    ordered = sorted(set(int(i) for i in ids))
    i = 0
    while i < len(ordered):
        j = i
        while j + 1 < len(ordered) and ordered[j + 1] == ordered[j] + 1:
            j += 1
        out.append(str(ordered[i]) if i == j else f"{ordered[i]}-{ordered[j]}")
        i = j + 1
    return ", ".join(out)


def _worst(values: dict[str, Any], unit: str, count: int = WORST) -> str:
    """The ``count`` largest of a per-robot dict: ``id 3: 1.02 m, id 4: 0.871 m``."""
    known = sorted(((float(v), k) for k, v in values.items() if v is not None), reverse=True)
    return ", ".join(f"id {k}: {quantity(v, unit)}" for v, k in known[:count])


def _arrival(metrics: dict[str, Any]) -> str:
    arrived = metrics.get("arrived") or {}
    final = metrics.get("final_position_error") or {}
    if not arrived:
        return "arrival: n/a (no robot)"
    missed = [int(k) for k, ok in arrived.items() if not ok]
    head = (f"arrival: {len(arrived) - len(missed)}/{len(arrived)} robots within "
            f"{quantity(metrics.get('arrival_tolerance', ARRIVAL_TOLERANCE), 'm')} of their "
            "reference at the end")
    if not missed:
        return f"{head}; largest final error ({_worst(final, 'm', 1)})"
    misses = {str(i): final.get(str(i)) for i in missed}
    if len(missed) == 1:
        return (f"{head}; NOT arrived: robot {missed[0]} (final error "
                f"{quantity(misses[str(missed[0])], 'm')})")
    return (f"{head}; NOT arrived: robots {id_ranges(missed)} (largest final errors: "
            f"{_worst(misses, 'm')})")


def _safety(metrics: dict[str, Any]) -> str:
    at = metrics.get("min_clearance_at") or {}
    where = (f" (robots {at['pair'][0]} and {at['pair'][1]} at t = {quantity(at['t'], 's')})"
             if at.get("pair") else "")
    parts = [f"min clearance {quantity(metrics.get('min_clearance'), 'm')}{where}",
             f"collisions {metrics.get('collisions', 0)} at samples, "
             f"{metrics.get('intersample_collisions', 0)} between samples"]
    if metrics.get("min_obstacle_clearance") is not None:
        parts.append(f"obstacle collisions {metrics.get('obstacle_collisions', 0)} (min "
                     f"clearance {quantity(metrics['min_obstacle_clearance'], 'm')})")
    parts.append(f"input bound violations {metrics.get('input_bound_violations', 0)}")
    parts.append(f"solver failures {metrics.get('solver_failures', 0)}")
    return "safety: " + ", ".join(parts)


def _tracking(metrics: dict[str, Any]) -> str:
    rms = {k: v for k, v in (metrics.get("rms_tracking_error") or {}).items() if v is not None}
    if not rms:
        return "tracking: n/a"
    if len(rms) <= WORST:
        listed = ", ".join(f"{k}: {quantity(v)}" for k, v in rms.items())
        text = f"tracking: RMS error by robot {listed} m"
    else:
        text = (f"tracking: RMS error median {quantity(float(np.median(list(rms.values()))), 'm')}"
                f" over {len(rms)} robots, largest ({_worst(rms, 'm', 3)})")
    cost = metrics.get("closed_loop_cost")
    return text + (f"; closed-loop cost {quantity(cost)}" if cost is not None else "")


def summarize(metrics: dict[str, Any]) -> str:
    """A run's end-of-run summary from its ``metrics.json`` dict: at most 6 lines, whatever
    the number of robots (per-robot lists name the worst few and count the rest).

    The first line says what ran and whether it completed; then safety, arrival (how many
    arrived, naming those that did not), tracking, controller time and, for a distributed
    run, its deadlines and messages.
    """
    mode = f" ({metrics['mode']})" if metrics.get("mode") else ""
    done = "completed" if metrics.get("completed") else "NOT completed"
    lines = [f"{metrics.get('scenario')} / {metrics.get('scheme')}{mode}: "
             f"{metrics.get('steps')} samples of "
             f"{metrics.get('planned_steps', metrics.get('steps'))}, {done}",
             _safety(metrics), _arrival(metrics), _tracking(metrics)]
    st = metrics.get("solve_time") or {}
    total = ("" if metrics.get("solve_time_source")
             else f", total {quantity(st.get('total_s'), 's')}")
    lines.append(f"{describe_solve_time(metrics)}{total}")
    if metrics.get("distributed"):
        missed = metrics.get("missed_deadlines_by_robot") or {}
        late = {k: v for k, v in missed.items() if v}
        worst = f" (most: {_worst(late, '', 3)})" if late else ""
        faulty = sum(int(v) for v in (metrics.get("faulty_messages") or {}).values())
        lines.append(f"distributed: missed deadlines {metrics.get('missed_deadlines', 0)}"
                     f"{worst}, invalid messages {metrics.get('invalid_messages', 0)}, "
                     f"{f'faulty inputs braked {faulty}, ' if faulty else ''}"
                     f"sample loop {quantity(metrics.get('sample_loop_wall_s'), 's')} wall")
    return "\n".join(lines)


def missed_goal(metrics: dict[str, Any]) -> str | None:
    """Why a run missed its goal (a collision, a robot that did not arrive, an incomplete
    run), or ``None`` when every robot arrived without any collision."""
    collisions = (int(metrics.get("collisions") or 0)
                  + int(metrics.get("intersample_collisions") or 0)
                  + int(metrics.get("obstacle_collisions") or 0))
    if collisions:
        return f"{collisions} collision(s)"
    if not metrics.get("completed"):
        return "the run did not complete"
    missed = [int(k) for k, ok in (metrics.get("arrived") or {}).items() if not ok]
    if missed:
        return f"robot(s) {id_ranges(missed)} did not arrive"
    return None
