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

__version__ = "0.1.0"

# public name -> module that defines it
_EXPORTS: dict[str, str] = {
    # scenarios
    "Bounds": "scenario",
    "RobotSpec": "scenario",
    "Scenario": "scenario",
    "Weights": "scenario",
    "builtin_scenario_names": "scenario",
    "load_scenario": "scenario",
    "parse_scenario": "scenario",
    "Obstacle": "obstacles",
    "Plant": "plant",
    "PlantSpec": "plant",
    "antipodal_swap": "fleets",
    "grid_to_grid": "fleets",
    "random_crossings": "fleets",
    # references
    "HarmonicReference": "references",
    "PointReference": "references",
    "Reference": "references",
    "WaypointReference": "references",
    "reference_from_dict": "references",
    # settings and rules
    "OSQPSettings": "qp",
    "SolverSettings": "settings",
    "RULES": "registry",
    "Rule": "rules",
    "default_rules": "registry",
    "describe_rules": "registry",
    "rule_names": "registry",
    "select_rules": "registry",
    # controllers
    "CentralizedController": "controllers",
    "ControlOutput": "controllers",
    "DecentralizedController": "controllers",
    "IterationReport": "rti",
    "PlanMessage": "controllers",
    # closed loop, records and metrics
    "ClosedLoopSimulation": "simulation",
    "SimulationOptions": "simulation",
    "simulate": "simulation",
    "RunRecord": "metrics",
    "RunRecorder": "recorder",
    "compute_metrics": "metrics",
    "load_trajectory": "metrics",
    "write_metrics": "metrics",
    "write_run": "metrics",
    "write_trajectory": "metrics",
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
    from .controllers import (
        CentralizedController,
        ControlOutput,
        DecentralizedController,
        PlanMessage,
    )
    from .errors import ProblemError, ScenarioError, SolverError, SqpmpcError
    from .fleets import antipodal_swap, grid_to_grid, random_crossings
    from .metrics import (
        RunRecord,
        compute_metrics,
        load_trajectory,
        write_metrics,
        write_run,
        write_trajectory,
    )
    from .obstacles import Obstacle
    from .plant import Plant, PlantSpec
    from .qp import OSQPSettings
    from .recorder import RunRecorder
    from .references import (
        HarmonicReference,
        PointReference,
        Reference,
        WaypointReference,
        reference_from_dict,
    )
    from .registry import RULES, default_rules, describe_rules, rule_names, select_rules
    from .rti import IterationReport
    from .rules import Rule
    from .scenario import (
        Bounds,
        RobotSpec,
        Scenario,
        Weights,
        builtin_scenario_names,
        load_scenario,
        parse_scenario,
    )
    from .settings import SolverSettings
    from .simulation import ClosedLoopSimulation, SimulationOptions, simulate


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
