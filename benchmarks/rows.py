"""Rows, results and targets of the IPOPT comparison (:mod:`benchmarks.compare_ipopt`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sqpmpc.problem.scenario import Scenario

__all__ = [
    "COMMAND",
    "DEFAULT_SCENARIOS",
    "DOC_PATH",
    "GOAL_TOLERANCE",
    "QUICK_T_END",
    "REFERENCE",
    "ROWS",
    "SEGMENT_REFERENCE",
    "TARGETS",
    "TIMING_SCENARIO",
    "RowResult",
    "RowSpec",
    "ScenarioResult",
]

DEFAULT_SCENARIOS = ("paper-s1", "paper-s2", "swap-6", "head-on", "crossing-4")
COMMAND = "python -m benchmarks.compare_ipopt"
DOC_PATH = Path(__file__).resolve().parent.parent / "docs" / "benchmarks.md"
QUICK_T_END = 30.0
GOAL_TOLERANCE = 0.05

TARGETS: dict[str, float] = {
    "rti_cost_ratio": 1.05,  # RTI closed-loop cost <= 1.05 x IPOPT centralized
    "sqp_cost_ratio": 1.01,  # SQP <= 1.01 x
    "rti_time_ratio": 5.0,  # IPOPT controller time / RTI controller time >= 5 (every row)
    "rti_time_ratio_central": 10.0,  # ... >= 10 on paper-s2 centralized
    "central_median_ms": 0.25,  # paper-s2 centralized RTI median sample
    "decentral_median_ms": 0.1,  # decentralized median per-robot sample
    "qp_overhead": 1.3,  # RTI: whole controller time / (QP update + solve wall time)
    "goal_m": GOAL_TOLERANCE,  # every robot ends within this of its goal
}
TIMING_SCENARIO = "paper-s2"


@dataclass(frozen=True)
class RowSpec:
    """One controller configuration of the comparison.

    Attributes
    ----------
    label
        Row name in the tables.
    kind
        ``"ipopt"`` (reference), ``"ipopt-segment"`` (the reference with the
        distance also required between samples), ``"ipopt-variant"``,
        ``"rti"`` or ``"sqp"`` (which cost target applies).
    scheme
        ``"centralized"`` or ``"decentralized"``.
    settings
        Keyword arguments of :class:`sqpmpc.control.settings.SolverSettings` (sqpmpc rows)
        or of :func:`benchmarks.ipopt_reference.simulate_ipopt` (IPOPT rows).
    """

    label: str
    kind: str
    scheme: str
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def is_ipopt(self) -> bool:
        """Whether the row is an IPOPT run."""
        return self.kind.startswith("ipopt")


REFERENCE = RowSpec("IPOPT centralized (reference)", "ipopt", "centralized")
SEGMENT_REFERENCE = RowSpec("IPOPT centralized, inter-sample safe", "ipopt-segment",
                            "centralized", {"intersample_points": 3})
ROWS: tuple[RowSpec, ...] = (
    REFERENCE,
    SEGMENT_REFERENCE,
    RowSpec("IPOPT centralized, primal-only warm start", "ipopt-variant", "centralized",
            {"warm_start_duals": False}),
    RowSpec("sqpmpc RTI centralized", "rti", "centralized"),
    RowSpec("sqpmpc RTI decentralized", "rti", "decentralized"),
    RowSpec("sqpmpc SQP centralized", "sqp", "centralized", {"iteration_scheme": "sqp"}),
    RowSpec("sqpmpc SQP decentralized", "sqp", "decentralized", {"iteration_scheme": "sqp"}),
    RowSpec("sqpmpc RTI centralized, exact Hessian", "rti", "centralized",
            {"hessian": "exact"}),
    RowSpec("sqpmpc RTI centralized, PIQP", "rti", "centralized", {"qp_solver": "piqp"}),
    RowSpec("sqpmpc RTI decentralized, PIQP", "rti", "decentralized", {"qp_solver": "piqp"}),
    RowSpec("sqpmpc RTI decentralized, DAQP", "rti", "decentralized", {"qp_solver": "daqp"}),
)


@dataclass
class RowResult:
    """Measured outcome of one row on one scenario.

    Attributes
    ----------
    spec
        The configuration.
    metrics
        :func:`sqpmpc.io.metrics.compute_metrics` of the kept run.
    timing
        sqpmpc only: summed ``assembly_s``, ``qp_s``, ``osqp_solve_s`` and
        ``total_s`` of the kept run (``None`` for IPOPT).
    controller_steps
        Controller calls: samples times controllers.
    wall_s
        Wall time of all repetitions, s.
    runs
        Repetitions made.
    deterministic
        Whether every repetition produced the same closed-loop trajectory.
    """

    spec: RowSpec
    metrics: dict[str, Any]
    timing: dict[str, float] | None
    controller_steps: int
    wall_s: float
    runs: int
    deterministic: bool = True

    @property
    def scenario_name(self) -> str:
        """Name of the scenario the row ran on."""
        return str(self.metrics["scenario"])

    @property
    def cost(self) -> float:
        """Closed-loop cost of the executed trajectory."""
        return float(self.metrics["closed_loop_cost"])

    @property
    def total_time_s(self) -> float:
        """Controller time summed over samples and controllers, s."""
        return float(self.metrics["solve_time"]["total_s"])

    @property
    def median_sample_ms(self) -> float:
        """Median over samples of the controller time summed over controllers, ms."""
        return float(self.metrics["solve_time"]["median_ms"])

    @property
    def median_per_robot_ms(self) -> float:
        """Largest per-robot median controller time, ms (decentralized: one QP per robot)."""
        return float(max(self.metrics["solve_time"]["per_robot_median_ms"].values()))

    @property
    def final_error(self) -> float:
        """Largest final distance of a robot to its reference, m."""
        return float(self.metrics["max_final_position_error"])

    @property
    def at_goal(self) -> bool:
        """Every robot ended within :data:`GOAL_TOLERANCE` of its goal."""
        return self.final_error <= GOAL_TOLERANCE


@dataclass
class ScenarioResult:
    """All rows of one scenario; ``rows[0]`` is the IPOPT reference."""

    scenario: Scenario
    rows: list[RowResult]

    @property
    def reference(self) -> RowResult:
        """The IPOPT reference row."""
        return self.rows[0]

    @property
    def segment_reference(self) -> RowResult | None:
        """The inter-sample-safe IPOPT row, if it ran."""
        return next((r for r in self.rows if r.spec.kind == "ipopt-segment"), None)
