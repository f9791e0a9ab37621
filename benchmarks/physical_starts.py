"""The nominal physics runs from several nearby starts: invariants on each, the cost paired.

A closed loop of robots that pass each other is chaotic: which robot goes first, and when
a brake fallback falls, turn on millimetres, and with them the closed-loop cost. The cost
of one physics run against one ideal-plant run is then one draw of that chance (moving
corridor's first robot by 1 mm moves its *ideal-plant* cost by up to 1.27x). This module
runs each nominal case from :data:`MOVES` (the first robot's start moved along x), on
both plants from the same start, and gives

- the invariants on every start: overlaps, arrivals, frozen robots (a failure at one
  start is a failure of the case);
- the cost ratio of each start's physics run against the ideal run *from the same
  start*, and their median: the statistic the benchmark's cost verdict uses;
- the spread of the ideal plant's own costs over the starts.
"""

from __future__ import annotations

import dataclasses
import statistics
from collections.abc import Callable
from typing import Any

from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.scenario import Scenario
from sqpmpc.sim.physics import PhysicalRobot
from sqpmpc.sim.record import RunRecord
from sqpmpc.sim.simulation import simulate

__all__ = ["MOVES", "StartsResult", "moved", "over_starts"]

MOVES = (-2e-3, -1e-3, 1e-3, 2e-3)
"""Where else the first robot starts, m along x, beside the scenario's own start."""


def moved(scenario: Scenario, dx: float) -> Scenario:
    """The scenario with its first robot starting ``dx`` m further along x."""
    robots = list(scenario.robots)
    x, y, psi = robots[0].initial_state
    robots[0] = dataclasses.replace(robots[0], initial_state=(x + dx, y, psi))
    return scenario.with_changes(robots=tuple(robots))


@dataclasses.dataclass(frozen=True)
class StartsResult:
    """One nominal case over its starts (the scenario's own first)."""

    moves: tuple[float, ...]
    runs: tuple[dict[str, Any], ...]
    """:func:`benchmarks.physical.run_physical`'s counts, one per start."""
    ideal_costs: tuple[float, ...]

    @property
    def ratios(self) -> list[float]:
        """Physics cost against the ideal cost from the same start, per start."""
        return [r["cost_ratio"] for r in self.runs]

    @property
    def median_ratio(self) -> float:
        return float(statistics.median(self.ratios))

    def failures(self, failed: Callable[[dict[str, Any]], list[str]]) -> list[str]:
        """``failed``'s reasons, per start that has any, naming the start."""
        return [f"start {1000 * dx:+.0f} mm: {', '.join(why)}"
                for dx, r in zip(self.moves, self.runs, strict=True) if (why := failed(r))]

    def cells(self) -> str:
        """Table cells: starts clean / all, each ratio, the median, the ideal spread."""
        base = self.ideal_costs[0]
        spread = [c / base for c in self.ideal_costs]
        return (" / ".join(f"{x:.3f}" for x in self.ratios) + f" | **{self.median_ratio:.3f}**"
                + f" | {min(spread):.3f} to {max(spread):.3f}")


def over_starts(scenario: Scenario, scheme: str, robot: PhysicalRobot,
                first: tuple[RunRecord, dict[str, Any]],
                run: Callable[[Scenario, str, PhysicalRobot, RunRecord], dict[str, Any]]
                ) -> StartsResult:
    """The case from the scenario's own start (``first``: its ideal record and physics
    counts, already run) and from every :data:`MOVES` start, both plants each."""
    moves, runs, costs = [0.0], [first[1]], [compute_metrics(first[0])["closed_loop_cost"]]
    for dx in MOVES:
        sc = moved(scenario, dx)
        ideal = simulate(sc, scheme)
        runs.append(run(sc, scheme, robot, ideal))
        costs.append(compute_metrics(ideal)["closed_loop_cost"])
        moves.append(dx)
    return StartsResult(tuple(moves), tuple(runs), tuple(costs))
