r"""The built-in liveness rules (see :mod:`sqpmpc.rules.base` for the interface).

Exact symmetry (head-on pairs, swaps, crossings) gives local NMPC standoff
equilibria, and plain RTI has a few more ways to stop short or to cycle. Each
rule below addresses one of them, deterministically and alike in every robot,
so that the decentralized robots stay consistent with each other. None of
them touches safety (the rows stay inner approximations with a hard stage 1,
every first input is verified): a rule chooses among safe motions.

=================  ==============================================================
rule               what it does
=================  ==============================================================
``keep-right``     rotates every collision normal by ``angle`` (per-stage growth
                   optional): the hyperplanes tilt so each robot sees room on
                   its right and symmetric pairs pass each other
``turn-limit``     a pair's normal turns at most ``max_turn`` between stages:
                   predictions that tunnel through each other between two
                   samples would otherwise flip the hyperplane
``touching-pairs`` decentralized: a pair inside the margin band repeats its
                   stage-1 row on stage 2, so the plan turns first instead of
                   "wait, then go" every sample
``stall-repair``   a robot whose guess has every ``|v| < speed`` while its goal is
                   farther than ``distance`` is linearized at ``v = +-speed``:
                   at ``v = 0`` the linearized unicycle cannot move sideways
                   (standing, or cycling its gear with no net motion, for
                   ``patience`` samples: whatever the guess)
``parking``        a robot near a reference at rest gets ``gain`` times its
                   position weight and a small linearization speed, so it does
                   not stop short of a goal beside it
``gear-cycle``     RTI: a robot no collision row holds that would reverse gear a
                   second sample in a row has that sample iterated to convergence
``detour``         a robot blocked by a neighbour (standing or cycling its gear)
                   for ``patience`` samples heads for a point to the right of it
                   for ``hold`` samples
``roundabout``     (:mod:`sqpmpc.rules.roundabout`) a crowd of robots ahead is passed
                   counter-clockwise along its right tangent: dense fleets
=================  ==============================================================
"""

from __future__ import annotations

import dataclasses
import numbers
from dataclasses import dataclass

import numba
import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.kernels.rules import detour_step, parking_mask, repair_guess, reversing, stall_repair
from sqpmpc.ocp.geometry import RowGeometry
from sqpmpc.rules.base import (
    Contribution,
    Rule,
    RuleContext,
    RuleInstance,
    SampleView,
    check_positive,
)

__all__ = [
    "Detour", "GearCycle", "KeepRight", "Parking", "StallRepair", "TouchingPairs", "TurnLimit",
]

_jit = numba.njit(cache=True, nogil=True)


# ----------------------------------------------------------------------------- geometry


class _KeepRightInstance(RuleInstance):
    rule: KeepRight
    hooks = ("rows",)

    def configure_rows(self, geometry: RowGeometry) -> RowGeometry:
        r = self.rule
        i = np.arange(self.context.horizon)
        angles = np.minimum(r.angle + i * r.growth, r.max_angle)
        return dataclasses.replace(geometry, rotation=np.ascontiguousarray(
            np.stack((np.cos(angles), np.sin(angles)), -1)))


@dataclass(frozen=True)
class KeepRight(Rule):
    """Rotate the collision normals clockwise-facing by ``angle`` rad (stage ``i``:
    ``min(angle + (i - 1) growth, max_angle)``)."""

    name = "keep-right"
    summary = "tilt every collision normal by 0.3 rad so symmetric encounters pass on the right"
    instance = _KeepRightInstance
    angle: float = 0.3
    growth: float = 0.0
    max_angle: float = 1.0

    def __post_init__(self) -> None:
        check_positive(self, "angle", "max_angle")
        check_positive(self, "growth", allow_zero=True)
        if self.angle >= np.pi / 2 or self.max_angle >= np.pi / 2:
            raise ProblemError(f"rule 'keep-right': angle and max_angle must be below pi/2, "
                               f"got {self.angle}, {self.max_angle}")
        if self.angle > self.max_angle:
            raise ProblemError(f"rule 'keep-right': angle ({self.angle}) must not exceed "
                               f"max_angle ({self.max_angle}), which caps every stage")


class _TurnLimitInstance(RuleInstance):
    rule: TurnLimit
    hooks = ("rows",)

    def configure_rows(self, geometry: RowGeometry) -> RowGeometry:
        return dataclasses.replace(geometry, max_turn=self.rule.max_turn)


@dataclass(frozen=True)
class TurnLimit(Rule):
    """A pair's collision normal turns at most ``max_turn`` rad between stages."""

    name = "turn-limit"
    summary = "a pair's collision normal turns at most 0.6 rad from one stage to the next"
    instance = _TurnLimitInstance
    max_turn: float = 0.6

    def __post_init__(self) -> None:
        check_positive(self, "max_turn")
        if self.max_turn >= np.pi:
            raise ProblemError(f"rule 'turn-limit': max_turn must be below pi, "
                               f"got {self.max_turn}")


class _TouchingInstance(RuleInstance):
    hooks = ("rows",)

    def configure_rows(self, geometry: RowGeometry) -> RowGeometry:
        return dataclasses.replace(geometry, hold_touching=True)


@dataclass(frozen=True)
class TouchingPairs(Rule):
    """Decentralized: a pair inside the margin band keeps its stage-1 row on stage 2."""

    name = "touching-pairs"
    summary = "decentralized: touching pairs repeat the stage-1 row on stage 2 (turn, then go)"
    instance = _TouchingInstance


# ----------------------------------------------------------------- linearization point


def _repair_speeds_within_bounds(context: RuleContext, speed: float
                                 ) -> tuple[float, float, float]:
    """Forward and backward repair speeds clipped to the bounds, and the "stalled" threshold.

    The threshold is at most the repair speeds' size, so a robot already at the
    (clipped) repair speed is not stalled.
    """
    ahead = context.speed_within_bounds(speed)
    back = context.speed_within_bounds(-speed)
    return ahead, back, min(speed, max(abs(ahead), abs(back)))


class _StallInstance(RuleInstance):
    rule: StallRepair
    hooks = ("guess",)
    counter_names = ("stall_repairs",)

    def __init__(self, rule: StallRepair, context: RuleContext) -> None:
        super().__init__(rule, context)
        self._ahead, self._back, self._slow = _repair_speeds_within_bounds(context, rule.speed)
        self._all = np.ones(context.own.size, dtype=np.bool_)
        self._still_for = np.zeros(context.own.size, dtype=np.int64)
        self._cycling = np.zeros(context.own.size, dtype=np.int64)  # gear reversals in a row
        self._stuck = np.zeros(context.own.size, dtype=np.bool_)
        self._speeds = np.zeros((context.own.size, context.horizon))  # the repaired guess
        self._params = np.array([rule.speed, rule.patience, rule.distance, self._slow,
                                 self._ahead, self._back, rule.cycle], dtype=float)  # kernel's

    def shape_guess(self, view: SampleView) -> Contribution | None:
        # standing for `patience` samples with the reference at rest: whatever the guess
        # plans; else every guess |v| < the repair speed (one kernel, the new speeds into
        # this rule's buffer: no contribution when it repaired nothing)
        repaired = stall_repair(view.guess_speeds, view.references, view.applied,
                                view.applied_before, view.own_states, self._params,
                                self._still_for, self._cycling, self._stuck, self._speeds)
        if not repaired:
            return None
        self.counts["stall_repairs"] += repaired
        return Contribution(guess_speeds=self._speeds)


@dataclass(frozen=True)
class StallRepair(Rule):
    """Linearize a stalled robot (every guess ``|v| < speed``; or, with a reference at
    rest over the horizon, standing for ``patience`` samples in a row, whatever the guess
    plans; goal farther than ``distance``) at ``v = +-speed`` towards its goal.

    *Standing*: applied ``|v| < speed``, or reversing gear ``cycle`` samples in a row
    with no net motion (:func:`sqpmpc.kernels.rules.idle`: RTI can cycle ``+v, -v``
    at a neighbour for ever, where the linearization at either gear cannot turn it).
    """

    name = "stall-repair"
    summary = "linearize a stopped robot far from its goal at a small speed (v = 0 cannot steer)"
    instance = _StallInstance
    speed: float = 0.05
    distance: float = 0.1
    patience: int = 10
    cycle: int = 2

    def __post_init__(self) -> None:
        check_positive(self, "speed", "distance", "patience", "cycle")
        for name in ("patience", "cycle"):
            if not isinstance(getattr(self, name), numbers.Integral):
                raise ProblemError(f"rule 'stall-repair': {name} must be an integer, "
                                   f"got {getattr(self, name)!r}")


class _ParkingInstance(RuleInstance):
    rule: Parking
    hooks = ("references", "guess")
    counter_names = ("parked_samples", "parking_repairs")

    def __init__(self, rule: Parking, context: RuleContext) -> None:
        super().__init__(rule, context)
        horizon_time = context.horizon * context.sample_time
        self.gain = rule.gain * max(1.0, (rule.horizon / horizon_time) ** 2)
        self.radius = max(rule.radius,
                          rule.reach * context.max_speed * max(horizon_time, rule.horizon))
        self._ahead, self._back, self._slow = _repair_speeds_within_bounds(context, rule.speed)
        self.parking = np.zeros(context.own.size, dtype=np.bool_)
        self._parked = 0
        self._speeds = np.zeros((context.own.size, context.horizon))  # the repaired guess

    def shape_references(self, view: SampleView) -> Contribution | None:
        parked = parking_mask(view.scenario_references, view.own_states, self.radius,
                              self.parking)
        out = None
        if parked < 0:  # the mask changed: new weights
            parked = -1 - parked
            out = Contribution(position_weight_scale=np.where(self.parking, self.gain, 1.0))
        self.counts["parked_samples"] += parked
        self._parked = parked  # how many park (the guess hook of the same sample reads it)
        return out

    def shape_guess(self, view: SampleView) -> Contribution | None:
        if not self._parked:  # nobody parks: nothing to repair
            return None
        repaired = repair_guess(view.guess_speeds, view.references, view.own_states,
                                self.parking, self._slow, self.rule.tolerance, self._ahead,
                                self._back, self._speeds)
        if not repaired:
            return None
        self.counts["parking_repairs"] += repaired
        return Contribution(guess_speeds=self._speeds)


@dataclass(frozen=True)
class Parking(Rule):
    r"""Weigh the position of a robot near a reference at rest ``gain`` times more.

    The parking radius is the larger of ``radius`` and ``reach`` times the
    distance the robot travels in ``max(N Ts, horizon)`` at full speed (1.2 m
    for the built-in bounds); the gain grows as ``(horizon / (N Ts))^2`` below
    ``horizon`` seconds, since turning within a shorter horizon costs that much
    more input energy. With the paper's weights the optimal plan stops short
    of a goal to the robot's side (converged IPOPT stops 0.07-0.17 m short).
    A parking robot whose guess is at rest farther than ``tolerance`` from its
    goal is linearized at ``+-speed``, as in ``stall-repair``.
    """

    name = "parking"
    summary = "near a resting reference: 20x position weight and a small linearization speed"
    instance = _ParkingInstance
    gain: float = 20.0
    horizon: float = 4.0
    radius: float = 0.25
    reach: float = 0.5
    tolerance: float = 0.01
    speed: float = 0.05

    def __post_init__(self) -> None:
        check_positive(self, "gain", "horizon", "radius", "reach", "tolerance", "speed")
        if self.gain <= 1.0:
            raise ProblemError(f"rule 'parking': gain must be > 1 (remove the rule to turn it "
                               f"off), got {self.gain}")


# ------------------------------------------------------------------------- after solve


class _GearCycleInstance(RuleInstance):
    rule: GearCycle
    hooks = ("after_solve",)
    counter_names = ("gear_cycle_samples",)

    def __init__(self, rule: GearCycle, context: RuleContext) -> None:
        super().__init__(rule, context)
        self._rti = context.iteration_scheme == "rti"
        self._cycle = np.zeros(context.own.size, dtype=np.bool_)

    def after_solve(self, view: SampleView) -> Contribution | None:
        if not self._rti:
            return None
        if not reversing(view.first_speeds, view.applied, view.applied_before,
                         self.rule.min_speed, self._cycle):
            return None
        if not np.count_nonzero(self._cycle & ~view.engaged()):
            return None
        self.counts["gear_cycle_samples"] += 1
        return Contribution(iterate=True)


@dataclass(frozen=True)
class GearCycle(Rule):
    """RTI: iterate a sample to convergence when a robot no collision row holds would
    reverse gear a second sample in a row (speeds above ``min_speed``)."""

    name = "gear-cycle"
    summary = "RTI: converge the sample (SQP) when a free robot reverses gear twice in a row"
    instance = _GearCycleInstance
    min_speed: float = 0.005

    def __post_init__(self) -> None:
        check_positive(self, "min_speed")


# ------------------------------------------------------------------------------ detour


class _DetourInstance(RuleInstance):
    rule: Detour
    hooks = ("references",)
    counter_names = ("detour_activations",)

    def __init__(self, rule: Detour, context: RuleContext) -> None:
        super().__init__(rule, context)
        m = context.own.size
        self.patience = rule.patience_centralized if context.scheme == "centralized" \
            else rule.patience
        self.kept = context.kept_distances()  # near: within what the rows keep + reach
        self._state = np.zeros((4, m), dtype=np.int64)  # the kernel's, by row:
        self.blocked_for, self.active_for, self.blocker, self.cycling = self._state
        self.blocker[:] = -1
        self._cos_cone = np.cos(rule.cone)
        self._params = np.array([rule.speed, rule.reach, self._cos_cone, self.patience,
                                 rule.hold, rule.cycle], dtype=float)  # the kernel's numbers
        self._turn = np.array([[np.cos(rule.angle), -np.sin(rule.angle)],
                               [np.sin(rule.angle), np.cos(rule.angle)]])

    def shape_references(self, view: SampleView) -> Contribution | None:
        r = self.rule
        positions = view.positions
        if positions.shape[0] < 2:
            return None
        activations = detour_step(positions, self.context.own, view.applied,
                                  view.applied_before, view.references, self.kept,
                                  self._params, self._state)
        if activations < 0:  # nobody detours
            return None
        self.counts["detour_activations"] += activations
        active = np.flatnonzero(self.active_for)
        own = self.context.own
        out = view.references.copy()
        for i in active:
            b = self.blocker[i]
            away = positions[own[i]] - positions[b]
            away = away / max(np.hypot(*away), 1e-12)
            # still blocked after each `hold` samples of detour: a wider one
            rounds = max(0, int(self.blocked_for[i]) - self.patience) // r.hold
            factor = min(r.radius_factor + r.escalation * rounds, r.max_factor)
            out[i] = positions[b] + factor * self.kept[i, b] * (self._turn @ away)
        return Contribution(references=out)


@dataclass(frozen=True)
class Detour(Rule):
    r"""Right-hand detour around a blocking neighbour.

    A robot is *blocked* when it stands (its last applied speed below ``speed``, or
    ``cycle`` gear reversals in a row with no net motion:
    :func:`sqpmpc.kernels.rules.idle`) and a
    neighbour closer than the kept distance plus ``reach`` lies within
    ``cone`` of the direction to its stage-N reference, which is farther than
    ``reach`` (the *kept* distance is the required one plus the rows' margin
    for the plant, :meth:`RuleContext.kept_distances`: robots with
    acceleration bounds never come closer than that, so ``reach`` stays free
    room). After ``patience`` blocked samples (``patience_centralized``
    for the centralized controller, whose joint optimization resolves most
    encounters itself) its reference on every stage becomes, for ``hold``
    samples (renewed while blocked), the point at ``radius_factor`` times the
    kept distance from the blocker, ``angle`` to the right of the
    direction from the blocker to itself: two robots doing so pass on their
    right. A robot still blocked after each further ``hold`` samples widens
    its detour by ``escalation`` (up to ``max_factor``): at the default 60
    degrees and factor 2 the target lies on the pair's mid-line, which two
    robots pressed together with a third beside them cannot always leave.
    """

    name = "detour"
    summary = "a robot blocked by a neighbour heads for a point to its right for a few samples"
    instance = _DetourInstance
    speed: float = 0.05
    reach: float = 0.3
    cone: float = float(np.deg2rad(75.0))
    patience: int = 2
    patience_centralized: int = 8
    hold: int = 6
    radius_factor: float = 2.0
    angle: float = float(np.deg2rad(60.0))
    escalation: float = 0.5
    max_factor: float = 4.0
    cycle: int = 4

    def __post_init__(self) -> None:
        check_positive(self, "speed", "reach", "cone", "patience", "patience_centralized",
                       "hold", "radius_factor", "angle", "max_factor", "cycle")
        check_positive(self, "escalation", allow_zero=True)
        if self.max_factor < self.radius_factor:
            raise ProblemError(f"rule 'detour': max_factor ({self.max_factor}) must be at "
                               f"least radius_factor ({self.radius_factor})")
        for name in ("patience", "patience_centralized", "hold", "cycle"):
            if not isinstance(getattr(self, name), numbers.Integral):
                raise ProblemError(f"rule 'detour': {name} must be an integer, "
                                   f"got {getattr(self, name)!r}")
