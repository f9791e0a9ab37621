"""Where the decentralized scheme loses: the decomposition or the predictions?

The decentralized RTI rows of ``docs/benchmarks.md`` cost more than the
centralized ones on the paper scenarios. Two causes are possible, and this
benchmark separates them by running, side by side on every built-in scenario:

- **centralized**: one QP for all robots (RTI and SQP);
- **decentralized**: one QP per robot with the neighbours' plans of the
  previous sample, each keeping half the distance on its side of the shared
  hyperplane (RTI and SQP, the default ``"shared"`` mode);
- **decentralized, paper mode**: each robot treats the neighbours' predicted
  positions as obstacles and keeps the whole distance (the seed paper's
  scheme);
- **decentralized with oracle predictions**: the same per-robot QPs, but at
  every sample each robot is handed, as its own and its neighbours' previous
  plans, the plans a centralized controller computes *on the same states at
  this sample* (it runs alongside; its inputs are not applied). The robots
  then split hyperplanes built from the best joint prediction available, with
  no lag and no disagreement between them.

If the oracle rows match the centralized cost, the gap is prediction quality
(one sample of lag, each robot guessing the others): better exchange could
close it. If they stay far above it, the gap is the decomposition itself:
splitting every pair constraint into two fixed half-planes removes the
joint freedom (one robot yielding more than the other) that the centralized
QP uses.

Reproduce (writes ``docs/decomposition.md``)::

    python -m benchmarks.decomposition
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.pipeline import ControlOutput
from sqpmpc.control.plans import PlanMessage
from sqpmpc.control.settings import SolverSettings
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import builtin_scenario_names, load_scenario
from sqpmpc.sim.record import RunRecord
from sqpmpc.sim.simulation import ClosedLoopSimulation, SimulationOptions, simulate

from .compare_ipopt import machine_info
from .report import publish
from .rows import DEFAULT_SCENARIOS

__all__ = ["OraclePredictionSimulation", "main"]

DOC_PATH = Path(__file__).resolve().parents[1] / "docs" / "decomposition.md"


class OraclePredictionSimulation(ClosedLoopSimulation):
    """Decentralized closed loop whose robots receive the centralized plans of each sample.

    At sample ``k`` a :class:`~sqpmpc.control.centralized.CentralizedController`
    solves on the measured states; robot ``j``'s plan of that solution is
    handed to every decentralized controller (robot ``j`` included) as the
    plan "published at ``k - 1``", shaped so that the controllers' one-step
    shift reproduces it exactly: stages ``0..N-1`` from the stored states and
    stage ``N`` from the last state and input.
    """

    def __init__(self, scenario: Scenario, settings: SolverSettings | None = None) -> None:
        super().__init__(scenario, "decentralized", settings, SimulationOptions())
        self.oracle = CentralizedController(scenario, self.settings)

    def step(self) -> None:
        """Compute the centralized plans on the current states, hand them out, advance."""
        k = self.k
        self.hand_out(k, self.oracle.step(self.t[k], self.states[k]))
        super().step()

    def hand_out(self, k: int, plan: ControlOutput) -> None:
        """Give every controller the centralized ``plan`` of sample ``k`` as plans of ``k - 1``."""
        N = self.scenario.horizon
        for j, controller in enumerate(self.controllers):
            xs, us = plan.predicted_states[j], plan.predicted_inputs[j]
            message = PlanMessage(controller.robot_id, k - 1, np.vstack((xs[:1], xs[:N])),
                                  us.copy())
            self.neighbour_plans[controller.robot_id] = message
            controller.published = message


def _row(name: str, record: RunRecord, reference_cost: float) -> str:
    m = compute_metrics(record)
    cost = float(m["closed_loop_cost"])
    unsafe = m["collisions"] + m["intersample_collisions"]
    return (f"| {name} | {cost:.3f} | {cost / reference_cost:.3f} | {unsafe} | "
            f"{m['min_clearance']:.4f} | {m['max_final_position_error']:.3f} |")


def run_scenario(name: str) -> list[str]:
    """Table rows of one scenario (centralized RTI cost is the ratio's denominator)."""
    scenario = load_scenario(name)
    rti, sqp = SolverSettings(), SolverSettings(iteration_scheme="sqp")
    central = simulate(scenario, "centralized", rti)
    c_cost = float(compute_metrics(central)["closed_loop_cost"])
    runs = [
        ("RTI centralized", central),
        ("SQP centralized", simulate(scenario, "centralized", sqp)),
        ("RTI decentralized", simulate(scenario, "decentralized", rti)),
        ("SQP decentralized", simulate(scenario, "decentralized", sqp)),
        ("RTI decentralized, paper mode",
         simulate(scenario, "decentralized", rti, SimulationOptions(decentralized_mode="paper"))),
        ("RTI decentralized, oracle predictions", OraclePredictionSimulation(scenario, rti).run()),
    ]
    rows = [_row(f"{name} | {label}", record, c_cost) for label, record in runs]
    for row in rows:
        print(row, file=sys.stderr, flush=True)
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.decomposition",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenarios", nargs="+", default=list(DEFAULT_SCENARIOS),
                        help=f"built-in names or files (the fleets swap-16, swap-64 are "
                             f"benchmarks.fleet's; built-ins: "
                             f"{', '.join(builtin_scenario_names())})")
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    lines = ["| scenario | controller | closed-loop cost | / RTI centralized | collisions at + "
             "between samples | min clearance m | max final error m |",
             "|---|---|---|---|---|---|---|"]
    for name in args.scenarios:
        lines += run_scenario(name)
    info = machine_info()
    report = f"""# Decentralized cost: decomposition or predictions?

Reproduce: `python -m benchmarks.decomposition`

{__doc__.split(chr(10) + chr(10), 1)[1].rsplit(chr(10) + chr(10) + "Reproduce", 1)[0]}

Machine: {info['CPU']}, {info['cores']}, Python {info['Python']}, OSQP {info['OSQP']};
{info['date']}; wall time {time.perf_counter() - t0:.0f} s. Default settings
everywhere (keep-right, detour, parking and gear-cycle rules on).

{chr(10).join(lines)}
"""
    publish(report, None if args.no_write else DOC_PATH)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
