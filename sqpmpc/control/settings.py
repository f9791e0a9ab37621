"""Settings of the controllers: the iteration, the collision rows, the rules, OSQP.

:class:`SolverSettings` is one frozen dataclass shared by both schemes:

- the iteration (:mod:`sqpmpc.ocp.iteration`): RTI or SQP, Hessian, discretization,
  tolerances, the first sample's SQP start and the per-sample time budget;
- the collision rows (:mod:`sqpmpc.ocp.collision_rows`): margin and slack price (the
  safety rows themselves are always on);
- the liveness rules (:mod:`sqpmpc.rules.liveness`), a tuple of rule objects: a
  rule is on when it is in the tuple (:func:`sqpmpc.rules.registry.select_rules`);
- OSQP (:class:`sqpmpc.qp.backend.OSQPSettings`).

Values are validated on construction; a bad value raises
:class:`~sqpmpc.errors.ProblemError` naming the field. No value means "off":
options that can be absent are ``None``.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.models.unicycle import DISCRETIZATIONS
from sqpmpc.qp.backend import QP_SOLVERS, OSQPSettings
from sqpmpc.rules.base import Rule
from sqpmpc.rules.registry import check_rules, default_rules

__all__ = ["BOUNDED_QP_SOLVER", "CENTRALIZED_QP_SOLVER", "FLEET_NEIGHBOUR_SLOTS",
           "FLEET_QP_SOLVER", "FLEET_ROBOTS", "QP_SOLVER_CHOICES",
           "SolverSettings", "neighbour_slots_argument"]

#: Scenarios with more robots than this are *fleets* for the ``"auto"`` settings.
FLEET_ROBOTS = 8
#: ``neighbour_slots="auto"`` on a fleet.
FLEET_NEIGHBOUR_SLOTS = 8
#: ``qp_solver="auto"`` on a fleet (:data:`BOUNDED_QP_SOLVER` on the other problems).
FLEET_QP_SOLVER = "piqp"
#: ``qp_solver="auto"`` where OSQP is fastest at the median: OSQP, warm-started, capped at
#: :data:`~sqpmpc.qp.backend.HANDOVER_ITERATIONS` iterations, PIQP for the QPs it leaves;
#: no QP then takes more than about 5 times OSQP's median work (``docs/speed.md``).
BOUNDED_QP_SOLVER = "osqp+piqp"
#: ``qp_solver="auto"`` for the centralized QP of at most :data:`FLEET_ROBOTS` robots of a
#: model without velocity states: the primal-dual active-set method
#: (:mod:`sqpmpc.qp.active_set`), whose warm-started working set is right at about 1.03
#: factorizations per QP, with PIQP behind it; measured on paper-s2 against OSQP on the
#: same QPs: about 3 times less QP time at N = 8 and 40, solutions exact to round-off
#: (``docs/engine.md``).
CENTRALIZED_QP_SOLVER = "active-set"
#: What ``qp_solver`` accepts.
QP_SOLVER_CHOICES = ("auto", *QP_SOLVERS)


@dataclass(frozen=True)
class SolverSettings:
    """Settings shared by both schemes.

    Attributes
    ----------
    iteration_scheme
        ``"rti"``: one QP per sample; ``"sqp"``: iterate to ``kkt_tolerance``.
    hessian
        ``"gauss-newton"`` or ``"exact"`` (PSD-projected dynamics curvature).
    discretization
        Prediction model: ``"euler"`` (paper eq. 3) or ``"rk4"``.
    max_sqp_iterations
        Iteration cap of SQP mode.
    kkt_tolerance
        KKT residual (infinity norm; stationarity and complementarity relative to
        the multipliers once their mean size exceeds 100,
        :func:`sqpmpc.kernels.ocp.kkt_residual`) at which SQP stops; it also stops
        on a step at the QP's resolution (:data:`sqpmpc.ocp.iteration.STEP_TOLERANCE`).
    first_sample_iterations
        SQP iterations at the first sample (a converged start for RTI).
    rti_kkt_threshold
        RTI: extra iterations while the KKT residual after the QP step
        exceeds this value, at most ``rti_max_iterations``; ``None``: never.
    rti_max_iterations
        See ``rti_kkt_threshold``.
    slack_penalty
        Price of the L1 slacks of collision rows on stages 2..N (exact penalty).
    collision_margin
        Added to every required distance in the QP rows (covers solver
        tolerance), m.
    time_budget
        Wall-clock seconds the iterations of one sample may take, or ``None``.
        Iterating (SQP, the first sample, a sample a rule asks to converge)
        starts no new QP once it is spent; the first QP always runs.
    rules
        The liveness rules, applied in registry order (default: all).
    neighbour_slots
        The collision slots of each robot, filled every sample with the nearest
        neighbours that can come within their distance over the horizon
        (``None``: one slot per other robot, always filled). Decentralized: the
        rows of a robot's QP; neighbours within reach left without a slot are
        kept safe by the first-input check
        (:meth:`sqpmpc.control.decentralized.DecentralizedController.select_neighbours`).
        Centralized: each robot's nearest pairs get rows on every stage, the
        other pairs within reach on stage 1 only
        (:func:`sqpmpc.kernels.collision.select_pairs`). ``"auto"`` (default):
        :data:`FLEET_NEIGHBOUR_SLOTS` on scenarios of more than
        :data:`FLEET_ROBOTS` robots, else ``None``.
    qp_solver
        QP backend: ``"osqp"``, ``"piqp"`` (:mod:`sqpmpc.qp.piqp`),
        ``"daqp"`` (:mod:`sqpmpc.qp.daqp`), ``"osqp+piqp"`` (OSQP for at
        most :data:`sqpmpc.qp.backend.HANDOVER_ITERATIONS` iterations, then PIQP, both
        updated in place), ``"active-set"`` (:mod:`sqpmpc.qp.active_set`, with PIQP
        behind it) or ``"auto"`` (default):
        :data:`FLEET_QP_SOLVER` for the decentralized robots of a fleet of more
        than :data:`FLEET_ROBOTS` robots (an interior-point method's time per
        QP is nearly constant, where OSQP's tail grows with the crowding:
        ``docs/fleet.md``), :data:`CENTRALIZED_QP_SOLVER` for the centralized QP
        of at most :data:`FLEET_ROBOTS` robots without velocity states,
        :data:`BOUNDED_QP_SOLVER`
        otherwise (OSQP's median, its tail cut at the hand-over: ``docs/speed.md``).
    osqp
        OSQP settings (its tolerances and rescue apply to PIQP too).
    """

    iteration_scheme: Literal["rti", "sqp"] = "rti"
    hessian: Literal["gauss-newton", "exact"] = "gauss-newton"
    discretization: str = "euler"
    max_sqp_iterations: int = 50
    kkt_tolerance: float = 1e-5
    first_sample_iterations: int = 30
    rti_kkt_threshold: float | None = None
    rti_max_iterations: int = 1
    slack_penalty: float = 50.0
    collision_margin: float = 1e-3
    time_budget: float | None = None
    rules: tuple[Rule, ...] = field(default_factory=default_rules)
    neighbour_slots: int | Literal["auto"] | None = "auto"
    qp_solver: str = "auto"
    osqp: OSQPSettings = field(default_factory=OSQPSettings)

    def __post_init__(self) -> None:
        if self.iteration_scheme not in ("rti", "sqp"):
            raise ProblemError(
                f"iteration_scheme must be 'rti' or 'sqp', got {self.iteration_scheme!r}")
        if self.hessian not in ("gauss-newton", "exact"):
            raise ProblemError(f"hessian must be 'gauss-newton' or 'exact', got {self.hessian!r}")
        if self.discretization not in DISCRETIZATIONS:
            raise ProblemError(
                f"discretization must be one of {DISCRETIZATIONS}, got {self.discretization!r}")
        for name in ("max_sqp_iterations", "first_sample_iterations", "rti_max_iterations"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ProblemError(f"{name} must be an integer >= 1, got {value!r}")
        for name in ("kkt_tolerance", "slack_penalty", "collision_margin"):
            _check_nonnegative(name, getattr(self, name))
        for name in ("rti_kkt_threshold", "time_budget"):
            value = getattr(self, name)
            if value is not None:
                _check_nonnegative(name, value)
        if self.neighbour_slots not in (None, "auto") and (
                isinstance(self.neighbour_slots, bool)
                or not isinstance(self.neighbour_slots, int | np.integer)
                or self.neighbour_slots < 1):
            raise ProblemError(f"neighbour_slots must be an integer >= 1, 'auto' or None, got "
                               f"{self.neighbour_slots!r}")
        if self.qp_solver not in QP_SOLVER_CHOICES:
            raise ProblemError(f"qp_solver must be one of {QP_SOLVER_CHOICES}, "
                               f"got {self.qp_solver!r}")
        if not isinstance(self.osqp, OSQPSettings):
            raise ProblemError(f"osqp must be OSQPSettings, got {type(self.osqp).__name__}")
        object.__setattr__(self, "rules", check_rules(tuple(self.rules)))

    def qp_solver_for(self, n_robots: int, scheme: str = "decentralized",
                      velocity_states: bool = False) -> str:
        """The QP backend for a scenario of ``n_robots`` (``"auto"`` resolved).

        The fleet solver serves the decentralized robots' small QPs; the
        centralized QP of a fleet (thousands of rows) stays with OSQP, whose
        sparse ADMM iterations were 4 times faster there than PIQP's
        factorizations (swap-32: median 46 against 186 ms per sample), capped
        at the hand-over like every QP outside a decentralized fleet. The
        centralized QP of a small group (at most :data:`FLEET_ROBOTS` robots) of a
        model without ``velocity_states`` (the paper's unicycle) goes to the active-set
        method first (:data:`CENTRALIZED_QP_SOLVER`). With velocity states (the
        acceleration-limited unicycle) its working set often failed to settle on the
        built-in scenarios (room-door: 190 of 200 QPs handed on), so OSQP's chain
        keeps those.
        """
        if self.qp_solver != "auto":
            return self.qp_solver
        if scheme == "centralized" and n_robots <= FLEET_ROBOTS and not velocity_states:
            return CENTRALIZED_QP_SOLVER
        fleet = n_robots > FLEET_ROBOTS and scheme == "decentralized"
        return FLEET_QP_SOLVER if fleet else BOUNDED_QP_SOLVER

    def neighbour_slots_for(self, n_robots: int) -> int | None:
        """The neighbour slots for a scenario of ``n_robots`` (``"auto"`` resolved)."""
        if self.neighbour_slots != "auto":
            return self.neighbour_slots
        return FLEET_NEIGHBOUR_SLOTS if n_robots > FLEET_ROBOTS else None

    def resolved(self, n_robots: int, scheme: str = "decentralized",
                 velocity_states: bool = False) -> SolverSettings:
        """These settings with every ``"auto"`` resolved for a scenario of ``n_robots``
        (whose robot model has ``velocity_states`` or not)."""
        return replace(self, qp_solver=self.qp_solver_for(n_robots, scheme, velocity_states),
                       neighbour_slots=self.neighbour_slots_for(n_robots))

    def rule(self, name: str) -> Rule | None:
        """The rule named ``name`` if it is on, else ``None``."""
        return next((r for r in self.rules if r.name == name), None)

    def without(self, *names: str) -> SolverSettings:
        """These settings with the named rules removed (unknown names refused)."""
        from sqpmpc.rules.registry import RULES

        unknown = [n for n in names if n not in RULES and self.rule(n) is None]
        if unknown:
            raise ProblemError(f"unknown rule(s) {', '.join(map(repr, unknown))}; the rules "
                               f"are {', '.join(RULES)}")
        return replace(self, rules=tuple(r for r in self.rules if r.name not in names))

    def with_rule(self, rule: Rule) -> SolverSettings:
        """These settings with ``rule`` added, or replacing the rule of the same name."""
        return replace(self, rules=tuple(r for r in self.rules if r.name != rule.name)
                       + (rule,))


def _check_nonnegative(name: str, value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
            np.isfinite(value) and value >= 0):
        raise ProblemError(f"{name} must be finite and >= 0, got {value!r}")


def neighbour_slots_argument(text: str) -> int | Literal["auto"] | None:
    """``--neighbour-slots``: an integer >= 1, ``all`` (``None``) or ``auto``."""
    word = text.strip().lower()
    if word == "auto":
        return "auto"
    if word == "all":
        return None
    try:
        value = int(word)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, 'all' or 'auto', "
                                         f"got {text!r}")
    return value
