"""Settings of the RTI/SQP iteration and of the rules around it (one frozen dataclass).

:class:`SolverSettings` gathers what both schemes share: the iteration
(RTI or SQP, Hessian, discretization, tolerances), the collision rows
(margin, slack price, keep-right rotation, normal turn limit) and the rules
that keep the closed loop live (stall repair, parking, gear cycle, detour),
plus the OSQP settings. Values are validated on construction; a bad value
raises :class:`~sqpmpc.errors.ProblemError` naming the field.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .deadlock import DetourSettings
from .errors import ProblemError
from .model import DISCRETIZATIONS
from .qp import OSQPSettings

__all__ = ["SolverSettings"]


@dataclass(frozen=True)
class SolverSettings:
    """Settings of the RTI/SQP iteration shared by both schemes.

    Attributes
    ----------
    iteration_scheme
        ``"rti"``: one QP per sample; ``"sqp"``: iterate to ``kkt_tolerance``.
    hessian
        ``"gauss-newton"`` or ``"exact"`` (PSD-projected dynamics curvature).
    discretization
        ``"euler"`` (paper eq. 3) or ``"rk4"``.
    max_sqp_iterations
        Iteration cap of SQP mode.
    kkt_tolerance
        KKT residual (infinity norm) at which SQP stops.
    first_sample_iterations
        SQP iterations allowed at the first sample (a converged start for RTI).
    rti_kkt_threshold
        In RTI mode, extra iterations are done while the KKT residual after the
        QP step exceeds this value (``inf`` disables), at most ``rti_max_iterations``.
    slack_penalty
        Price of the L1 slacks of collision rows on stages 2..N (exact penalty).
    collision_margin
        Added to every required distance in the QP (covers solver tolerance), m.
    keep_right_angle, keep_right_growth, keep_right_max
        Symmetry-breaking rotation of the collision normals: stage ``i`` (1..N)
        is rotated by ``min(keep_right_angle + (i - 1) keep_right_growth,
        keep_right_max)`` rad. Growing angles make the predicted hyperplanes turn,
        so robots held in a standoff see room to their right in later stages.
    max_normal_turn
        Largest turn of a pair's collision normal between consecutive stages, rad:
        predictions that tunnel through each other between two samples would
        otherwise flip the hyperplane (see :func:`sqpmpc.collision.limit_turning`).
    stall_speed, stall_distance
        Controllability repair: a robot whose guess has every ``|v| < stall_speed``
        while its stage-N reference is farther than ``stall_distance`` is
        linearized at ``v = ±stall_speed`` (towards the reference) instead. At
        ``v = 0`` the linearized unicycle cannot move sideways (``A`` loses its
        heading-position coupling), so a stopped robot would never see that
        turning opens a way around an obstacle. Only the linearization point
        changes; stage 1 stays exact because its heading is measured.
        ``0`` disables.
    parking_gain, parking_horizon, parking_radius, parking_reach, parking_tolerance
        Parking rule: a robot whose (scenario) reference is at rest over the
        whole horizon and within the parking radius, the larger of
        ``parking_radius`` and ``parking_reach`` times the distance it can
        travel in ``max(N Ts, parking_horizon)`` (``v_max`` from the bounds;
        1.2 m with the defaults and the built-in scenarios' bounds; shorter
        horizons stop farther short), has its position weight
        multiplied by the parking gain, and is linearized at a small speed
        (as for ``stall_speed``) while farther than ``parking_tolerance``. The
        gain is ``parking_gain`` for horizons of ``parking_horizon`` seconds or
        more and grows as ``(parking_horizon / (N Ts))^2`` below: turning by a
        given angle within a shorter horizon costs that much more input
        energy. With the paper's weights the unicycle's optimal plan stops
        short of a goal that lies to its side, because turning costs more
        input energy over the horizon than the remaining error costs:
        converged IPOPT stops 0.07-0.17 m short of a goal 0.5-1 m to a robot's
        side, perturbed swap-6 runs stopped 0.06-0.15 m short, and with 0.6-1.4 s
        horizons (``Ts = 0.1 s``) lone robots stopped 0.28-1.06 m short. The
        executed trajectory's cost is still measured with the scenario's
        weights. ``parking_gain = 1`` disables.
    gear_cycle_sqp
        RTI only: when a robot that no collision row holds (every multiplier
        of its collision rows below 1e-4) would reverse gear for the second
        sample in a row (applied speeds ``+, -`` then ``+``, or ``-, +`` then
        ``-``, each above ``stall_speed / 10`` in size), the sample is iterated
        to convergence (SQP with line search, from the RTI step). One QP
        linearized at a plan of the other gear can land on the mirror plan,
        and the loop then alternates forward-left / reverse-right plans for
        ever (measured: a lone robot of a perturbed crossing-4 run, 40 samples,
        1.69 m from its goal). The trigger needs two reversals in a row, so an
        ordinary single gear change costs nothing; robots in an encounter are
        left to RTI because the converged OCP is what stands off in symmetric
        encounters.
    time_budget
        Wall-clock seconds the iterations of one sample may take (0: no
        limit). Iterating (SQP mode, the first sample, a gear-cycle sample)
        starts no new QP once it is spent and keeps the last iterate; the
        first QP always runs. For real time, with ``osqp.time_limit``
        bounding each QP.
    """

    iteration_scheme: Literal["rti", "sqp"] = "rti"
    hessian: Literal["gauss-newton", "exact"] = "gauss-newton"
    discretization: str = "euler"
    max_sqp_iterations: int = 50
    kkt_tolerance: float = 1e-5
    first_sample_iterations: int = 30
    rti_kkt_threshold: float = float("inf")
    rti_max_iterations: int = 1
    slack_penalty: float = 50.0
    collision_margin: float = 1e-3
    keep_right_angle: float = 0.3
    keep_right_growth: float = 0.0
    keep_right_max: float = 1.0
    stall_speed: float = 0.05
    max_normal_turn: float = 0.6
    stall_distance: float = 0.1
    parking_gain: float = 20.0
    parking_horizon: float = 4.0
    parking_radius: float = 0.25
    parking_reach: float = 0.5
    parking_tolerance: float = 0.01
    gear_cycle_sqp: bool = True
    time_budget: float = 0.0
    osqp: OSQPSettings = field(default_factory=OSQPSettings)
    detour: DetourSettings = field(default_factory=DetourSettings)

    def keep_right_angles(self, horizon: int) -> np.ndarray:
        """Per-stage rotation angles ``(N,)`` of the collision normals, rad."""
        i = np.arange(horizon)
        return np.minimum(self.keep_right_angle + i * self.keep_right_growth, self.keep_right_max)

    def __post_init__(self) -> None:
        if self.iteration_scheme not in ("rti", "sqp"):
            raise ProblemError(
                f"iteration_scheme must be 'rti' or 'sqp', got {self.iteration_scheme!r}"
            )
        if self.hessian not in ("gauss-newton", "exact"):
            raise ProblemError(f"hessian must be 'gauss-newton' or 'exact', got {self.hessian!r}")
        if self.discretization not in DISCRETIZATIONS:
            raise ProblemError(
                f"discretization must be one of {DISCRETIZATIONS}, got {self.discretization!r}"
            )
        for name in ("max_sqp_iterations", "first_sample_iterations", "rti_max_iterations"):
            if int(getattr(self, name)) < 1:
                raise ProblemError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not (np.isfinite(self.parking_gain) and self.parking_gain >= 1.0):
            raise ProblemError(f"parking_gain must be finite and >= 1, got {self.parking_gain}")
        for name in ("kkt_tolerance", "slack_penalty", "collision_margin", "stall_speed",
                     "stall_distance", "parking_horizon", "parking_radius", "parking_reach",
                     "parking_tolerance", "time_budget"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ProblemError(f"{name} must be finite and >= 0, got {value}")
