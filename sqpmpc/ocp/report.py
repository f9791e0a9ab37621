"""What one call of the iteration did (:class:`IterationReport`) and what it needs from a
collision model (:class:`CollisionRows`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from sqpmpc.qp.backend import OSQPSettings, QPResult

__all__ = ["CollisionRows", "IterationReport", "IterationSettings"]



class IterationSettings(Protocol):
    """What the iteration reads of the controllers' settings
    (:class:`sqpmpc.control.settings.SolverSettings` has every field; see it for their meaning)."""

    iteration_scheme: str
    hessian: str
    discretization: str
    max_sqp_iterations: int
    kkt_tolerance: float
    first_sample_iterations: int
    rti_kkt_threshold: float | None
    rti_max_iterations: int
    slack_penalty: float
    time_budget: float | None
    osqp: OSQPSettings
    qp_solver: str


class CollisionRows(Protocol):
    """What the iteration needs from a collision model (see :mod:`sqpmpc.ocp.collision_rows`)."""

    stage_one_overrides: int

    def write_rows(self, states: np.ndarray, A_out: np.ndarray,
                   lower_out: np.ndarray) -> None: ...


@dataclass
class IterationReport:
    """What one call of :meth:`MultipleShootingSQP.solve` did.

    Attributes
    ----------
    success
        Every QP solved; ``states``/``inputs`` hold the new iterate.
    iterations
        QPs solved.
    kkt_residual
        Last KKT residual evaluated (``nan`` if none was).
    converged
        SQP mode: the KKT tolerance was met.
    status
        OSQP status of the last QP.
    assembly_time, qp_time, osqp_solve_time, total_time
        Seconds: linearization and value writes, ``update`` + ``solve`` wall
        time, OSQP's own solve time, and the whole call.
    """

    success: bool
    iterations: int
    kkt_residual: float
    converged: bool
    status: str
    assembly_time: float
    qp_time: float
    osqp_solve_time: float
    total_time: float
    qp_iterations: int = 0
    last_qp: QPResult | None = None
