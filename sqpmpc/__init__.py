"""sqpmpc: real-time sparse-QP NMPC for fleets of unicycle robots.

The public API, importable from the package itself::

    import sqpmpc

    scenario = sqpmpc.load_scenario("paper-s2")
    record = sqpmpc.ClosedLoopSimulation(scenario, "decentralized").run()
    print(sqpmpc.compute_metrics(record)["min_clearance"])

- problem data: :class:`Scenario` (:class:`RobotSpec`, :class:`Weights`,
  :class:`Bounds`, :class:`Obstacle`, :class:`PlantSpec`), :func:`load_scenario`,
  :func:`builtin_scenario_names`, the fleet generators :func:`antipodal_swap`,
  :func:`random_crossings`, :func:`grid_to_grid`;
- references: :class:`HarmonicReference`, :class:`PointReference`,
  :class:`WaypointReference`;
- settings: :class:`SolverSettings`, :class:`OSQPSettings` and the rules
  (:func:`select_rules`, :func:`default_rules`, :func:`rule_names`, ...);
- controllers: :class:`CentralizedController`, :class:`DecentralizedController`,
  their per-sample :class:`ControlOutput` and the exchanged :class:`PlanMessage`;
- closed loop and results: :class:`Plant` (how simulated robots move),
  :class:`ClosedLoopSimulation`,
  :class:`SimulationOptions`, :class:`RunRecord`, :func:`compute_metrics`,
  :func:`write_run`, :func:`load_trajectory`;
- errors: :class:`SqpmpcError` and its subclasses.

The names are loaded on first use (``import sqpmpc`` itself imports neither
numba nor the QP solvers); the compiled kernels are compiled or loaded from
their cache when the first controller is constructed.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from sqpmpc.version import __version__

# public name -> module that defines it
_EXPORTS: dict[str, str] = {
    # scenarios
    "Bounds": "problem.scenario",
    "RobotSpec": "problem.scenario",
    "Scenario": "problem.scenario",
    "Weights": "problem.scenario",
    "builtin_scenario_names": "problem.scenario_file",
    "load_scenario": "problem.scenario_file",
    "parse_scenario": "problem.scenario_file",
    "Obstacle": "problem.obstacles",
    "PolygonObstacle": "problem.polygons",
    "Plant": "problem.plant",
    "PlantSpec": "problem.plant",
    "antipodal_swap": "problem.fleets",
    "grid_to_grid": "problem.fleets",
    "random_crossings": "problem.fleets",
    # references
    "HarmonicReference": "problem.references",
    "PointReference": "problem.references",
    "Reference": "problem.references",
    "WaypointReference": "problem.references",
    "reference_from_dict": "problem.references",
    # settings and rules
    "OSQPSettings": "qp.backend",
    "SolverSettings": "control.settings",
    "RULES": "rules.registry",
    "Rule": "rules.base",
    "default_rules": "rules.registry",
    "describe_rules": "rules.registry",
    "rule_names": "rules.registry",
    "select_rules": "rules.registry",
    # controllers
    "CentralizedController": "control.centralized",
    "ControlOutput": "control.pipeline",
    "DecentralizedController": "control.decentralized",
    "IterationReport": "ocp.report",
    "PlanMessage": "control.plans",
    # closed loop, records and metrics
    "ClosedLoopSimulation": "sim.simulation",
    "SimulationOptions": "sim.simulation",
    "simulate": "sim.simulation",
    "RunRecord": "sim.record",
    "RunRecorder": "io.recorder",
    "compute_metrics": "io.metrics",
    "load_trajectory": "io.files",
    "write_metrics": "io.files",
    "write_run": "io.files",
    "write_trajectory": "io.files",
    # errors
    "ProblemError": "errors",
    "ScenarioError": "errors",
    "SolverError": "errors",
    "SqpmpcError": "errors",
}

__all__ = [
    "__version__",
    "Bounds",
    "RobotSpec",
    "Scenario",
    "Weights",
    "builtin_scenario_names",
    "load_scenario",
    "parse_scenario",
    "Obstacle",
    "PolygonObstacle",
    "Plant",
    "PlantSpec",
    "antipodal_swap",
    "grid_to_grid",
    "random_crossings",
    "HarmonicReference",
    "PointReference",
    "Reference",
    "WaypointReference",
    "reference_from_dict",
    "OSQPSettings",
    "SolverSettings",
    "RULES",
    "Rule",
    "default_rules",
    "describe_rules",
    "rule_names",
    "select_rules",
    "CentralizedController",
    "ControlOutput",
    "DecentralizedController",
    "IterationReport",
    "PlanMessage",
    "ClosedLoopSimulation",
    "SimulationOptions",
    "simulate",
    "RunRecord",
    "RunRecorder",
    "compute_metrics",
    "load_trajectory",
    "write_metrics",
    "write_run",
    "write_trajectory",
    "ProblemError",
    "ScenarioError",
    "SolverError",
    "SqpmpcError",
]

if TYPE_CHECKING:  # the same names, for type checkers and editors
    from sqpmpc.control.centralized import CentralizedController
    from sqpmpc.control.decentralized import DecentralizedController
    from sqpmpc.control.pipeline import ControlOutput
    from sqpmpc.control.plans import PlanMessage
    from sqpmpc.control.settings import SolverSettings
    from sqpmpc.errors import ProblemError, ScenarioError, SolverError, SqpmpcError
    from sqpmpc.io.files import load_trajectory, write_metrics, write_run, write_trajectory
    from sqpmpc.io.metrics import compute_metrics
    from sqpmpc.io.recorder import RunRecorder
    from sqpmpc.ocp.report import IterationReport
    from sqpmpc.problem.fleets import antipodal_swap, grid_to_grid, random_crossings
    from sqpmpc.problem.obstacles import Obstacle
    from sqpmpc.problem.plant import Plant, PlantSpec
    from sqpmpc.problem.polygons import PolygonObstacle
    from sqpmpc.problem.references import (
        HarmonicReference,
        PointReference,
        Reference,
        WaypointReference,
        reference_from_dict,
    )
    from sqpmpc.problem.scenario import Bounds, RobotSpec, Scenario, Weights
    from sqpmpc.problem.scenario_file import builtin_scenario_names, load_scenario, parse_scenario
    from sqpmpc.qp.backend import OSQPSettings
    from sqpmpc.rules.base import Rule
    from sqpmpc.rules.registry import (
        RULES,
        default_rules,
        describe_rules,
        rule_names,
        select_rules,
    )
    from sqpmpc.sim.record import RunRecord
    from sqpmpc.sim.simulation import ClosedLoopSimulation, SimulationOptions, simulate



def __getattr__(name: str) -> Any:
    """Import the module of a public name on first use (PEP 562)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'sqpmpc' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
