r"""Pairwise collision avoidance (paper eq. 5) as separating hyperplanes.

The distance constraint :math:`\|p_j - p_l\| \ge d_{jl}` is non-convex. Its
linearization at :math:`(\bar p_j, \bar p_l)` is the separating hyperplane

.. math::

    n^\top (p_j - p_l) \ge d_{jl}, \qquad n = \frac{\bar p_j - \bar p_l}{\|\bar p_j - \bar p_l\|}.

Safety rows (always on; listed by ``sqpmpc rules``)
----------------------------------------------------
These are the safety argument, not heuristics; no option removes them.

``inner-approximation``
    :math:`\|p_j - p_l\| \ge n^\top(p_j - p_l)` for any unit :math:`n`, so a
    satisfied row implies the true distance, whatever normal the liveness
    rules chose (rotated, turn-limited, held).
``stage-one-override``
    Stage 1 is hard (stages 2..N carry L1 slacks). If the stage-1 normal does
    not keep the *current* configuration feasible,
    :math:`n^\top(p_j(k) - p_l(k)) < d_{jl}`, the normal of the current
    positions is used instead and the right-hand side is capped at the
    current projected gap: stopping (``v = 0``, exact for every
    discretization) always satisfies stage 1, so the QP stays feasible and a
    safe configuration stays safe.
``overlap-recovery``
    A pair already inside its true distance (a push, a slip, a robot that did
    not move as predicted) cannot keep it over the next sample, so the check
    of the first input below would refuse every input, and the brake that
    follows never separates it: the controller would brake for ever. For such
    a pair alone the check asks instead that the predicted relative segment
    comes no closer than the current distance (less the solver tolerance,
    ``collision_margin``). The stage-1 row of the pair is then the
    ``stage-one-override``'s non-decreasing separation along the current
    normal (which implies it), and its rows of stages 2..N ask for the full
    distance (with slacks), so the plan separates the pair as fast as its
    bounds let it and the robots go on. Pairs that are apart keep every
    guarantee above unchanged. The same holds against obstacles
    (:class:`sqpmpc.ocp.obstacle_rows.ObstacleRows`) and, decentralized, is
    what the shared check already does inside the margin band.
``missing-neighbour-reach``
    Decentralized: a neighbour whose fresh plan is missing can do anything
    within its bounds. Stage 1 keeps :math:`d + r` from its current position,
    :math:`r = T_s v_{max}` its one-sample reach, if the current distance
    allows, and otherwise does not approach it (and the first-input check
    accepts only standing still). A departed robot, braked by its plant, can
    only slow down: from its second braked sample its reach is what it moved
    over the sample before (:meth:`ExternalCollisionModel.set_reach`).

Then the first input is *verified* before it is applied
(:meth:`PairwiseCollisionModel.first_input_safe`,
:meth:`ExternalCollisionModel.first_stage_safe`): along the straight segment
the Euler plant moves on, not only at the next sample.

**Shared responsibility (decentralized).** Robots ``j`` and ``l`` build the
same hyperplane from the same exchanged predictions and each keeps half the
distance on its own side of the mid-line: :math:`n^\top p_j \ge c + d/2` and
:math:`-n^\top p_l \ge -c + d/2` imply :math:`n^\top(p_j - p_l) \ge d`. On
stage 1 the offset :math:`c` is clipped so that each current position stays on
its side. The row geometry (rotation, turn limit, holding) comes from the
rules through :class:`sqpmpc.ocp.geometry.RowGeometry`; the rows are built by the
compiled kernels of :mod:`sqpmpc.kernels.collision`.
"""

from __future__ import annotations

import math

import numpy as np

from sqpmpc.kernels.collision import (
    halfplanes_hold_path,
    obstacle_rows,
    pair_rows,
    pairs_keep_distance,
    segment_keeps_distance,
    select_pairs,
    shared_rows,
)
from sqpmpc.kernels.rules import hold_touching_rows, inside_pairs
from sqpmpc.ocp.geometry import RowGeometry
from sqpmpc.problem.margins import required_height
from sqpmpc.problem.plant import largest_deviation

__all__ = [
    "MISSING", "OBSTACLE", "OFF", "SHARED", "ExternalCollisionModel", "PairwiseCollisionModel",
]

#: Slot kinds of :class:`ExternalCollisionModel`.
OFF, SHARED, OBSTACLE, MISSING = 0, 1, 2, 3


class PairwiseCollisionModel:
    r"""Internal pair rows of the centralized QP (both robots are variables).

    Parameters
    ----------
    pairs
        ``(P, 2)`` local robot indices.
    required
        ``(P,)`` true required centre distances :math:`(d_j + d_l)/2`.
    margin
        Added to ``required`` in the QP rows, m.
    geometry
        Row geometry from the rules.
    recovery
        The ``overlap-recovery`` rule's tolerance, m (see :meth:`first_input_safe`);
        negative: off (a pair inside its distance fails every check).
    deviation
        ``(alpha_max, beta_max)`` of :func:`sqpmpc.problem.margins.row_deviation` (robots
        with velocity states), or ``None``. With it the rows keep, beyond the check line
        ``required + base_margin`` (:mod:`sqpmpc.problem.margins`), twice what a robot's
        row keeps in the decentralized scheme: :math:`2L` at stages 2..N and
        :math:`\max(2L, m_2(h_0))` at stage 1, :math:`h_0` the pair's current height above
        the line and :math:`m_2` the required height of a pair whose two paths each
        stray by up to :math:`\alpha s + \beta s(1-s)` (:math:`2\alpha`, :math:`2\beta`),
        never more than the current gap; a pair inside its check line keeps ``margin``
        at stages 2..N.
    base_margin
        See ``deviation`` (the solver's margin).
    """

    def __init__(self, pairs: np.ndarray, required: np.ndarray, margin: float,
                 geometry: RowGeometry, recovery: float = -1.0,
                 deviation: tuple[float, float] | None = None,
                 base_margin: float = 0.0) -> None:
        self.recovery = float(recovery)
        self.pairs = np.ascontiguousarray(np.asarray(pairs, dtype=np.int64).reshape(-1, 2))
        self.safe_distance = np.asarray(required, dtype=float)
        self.deviation = None if deviation is None else (2.0 * float(deviation[0]),
                                                         2.0 * float(deviation[1]))
        #: ``(P,)`` the pair's check line: the true distance plus the solver's margin
        self.check_line = self.safe_distance + float(base_margin)
        #: ``(P,)`` the rows' distance with the old margin (``margin``)
        self.old_required = self.safe_distance + float(margin)
        #: the pair's fixed point 2 L (``deviation``; 0 without it), m
        self.steady = 0.0 if self.deviation is None else float(
            largest_deviation(*self.deviation))
        if self.deviation is None:
            self.required = self.old_required
        else:  # stages 2..N keep 2 L (stage 1: write_rows)
            self.required = self.check_line + self.steady
        self.geometry = geometry
        self.current_positions = np.zeros((0, 2))
        self.stage_one_overrides = 0
        self._scratch = np.empty((geometry.rotation.shape[0], 2))
        #: ``(P,)`` stages with a row per pair (:func:`select_pairs`); all by default
        self.stages = np.full(self.pairs.shape[0], geometry.rotation.shape[0], dtype=np.int64)

    def select(self, radius: np.ndarray, slots: int) -> tuple[int, int]:
        """Neighbour slots for the pair rows at the current positions (see
        :func:`sqpmpc.kernels.collision.select_pairs`); returns the full and stage-1-only
        pair counts."""
        return select_pairs(self.pairs, self.current_positions, radius, slots,
                            self.geometry.rotation.shape[0], self.stages)

    def set_current_positions(self, positions: np.ndarray) -> None:
        """Measured positions ``(m, 2)`` used by the stage-1 rule."""
        self.current_positions = np.ascontiguousarray(positions, dtype=float)

    def write_rows(self, states: np.ndarray, A_out: np.ndarray, lower_out: np.ndarray) -> None:
        """Rows at linearization ``states (m, N+1, 3)`` into ``(P, N, 4)`` and ``(P, N)``."""
        if self.pairs.shape[0] == 0:
            return
        self.stage_one_overrides = pair_rows(
            self.pairs, self.current_positions, states, self.required, self.geometry.rotation,
            self.geometry.kernel_max_turn, A_out, lower_out, self._scratch, self.stages)
        if self.deviation is not None:
            self._keep_stage_one(A_out, lower_out)

    def _keep_stage_one(self, A_out: np.ndarray, lower_out: np.ndarray) -> None:
        r"""Stage 1 of every pair keeps :math:`\max(2L, m_2(h_0))` beyond its check line,
        never more than the pair's current gap along the row (``deviation``)."""
        on = self.stages > 0
        if not on.any():
            return
        p = self.current_positions
        a, b = self.pairs[on, 0], self.pairs[on, 1]
        normal = A_out[on, 0, :2]
        gap = np.einsum("ij,ij->i", normal, p[a] - p[b])  # along the stage-1 row
        line = self.check_line[on]
        alpha, beta = self.deviation
        own = np.maximum(required_height(gap - line, alpha, beta), self.steady)
        first = lower_out[on, 0]
        lower_out[on, 0] = np.maximum(first, np.minimum(line + own, gap))
        # a pair inside its check line (pushed, slipped) keeps the old margin at stages
        # 2..N: its plan then separates it at once, as the overlap-recovery check needs
        # (with 2 L a pushed head-on pair's plans failed the check sample after sample)
        inside = np.flatnonzero(on)[gap < line]
        if inside.size:
            later = lower_out[inside, 1:]
            lower_out[inside, 1:] = np.where(np.isfinite(later),
                                             self.old_required[inside, None], later)

    def first_input_safe(self, now: np.ndarray, nxt: np.ndarray,
                         growth: np.ndarray | None = None) -> bool:
        """Every pair keeps its true distance along the straight segments ``now -> nxt``
        (``growth (m,)``: how far each robot's true path may stray, per unit of ``s``);
        a pair already inside it comes no closer (``overlap-recovery``, if on)."""
        if growth is None:
            growth = np.zeros(now.shape[0])
        return bool(pairs_keep_distance(self.pairs, now, nxt, self.safe_distance,
                                        np.ascontiguousarray(growth, dtype=float),
                                        self.recovery))


class ExternalCollisionModel:
    r"""Rows of one robot against neighbours whose predictions are data.

    Each slot ``e`` is one of (:data:`SHARED`, :data:`OBSTACLE`, :data:`MISSING`,
    :data:`OFF`):

    - shared: the fixed common hyperplane of the two exchanged predictions,
      half the distance each (a linear row);
    - obstacle: the neighbour's prediction is a moving obstacle, the full
      distance is kept and the row relinearized at the own iterate (the
      paper's literal scheme);
    - missing: a neighbour of the shared scheme whose plan did not arrive:
      stages 2..N as an obstacle on its extrapolated prediction, stage 1 by
      the ``missing-neighbour-reach`` safety row;
    - off: no row.

    **First-stage check** (:meth:`first_stage_safe`): for a shared slot with
    stage-1 normal :math:`n_1`, current projected gap :math:`g` and true
    distance :math:`D`: if :math:`g \ge D + \text{margin}` each robot keeps
    :math:`n_1^\top p \ge c + D/2`; otherwise (inside the margin band, where
    the row only forbids approaching) each gives up at most
    :math:`\max(0, g - D)/2` from the common current mid-line. Either way the
    two accepted positions keep :math:`n_1^\top(p_j - p_l) \ge \min(D, g)`, so
    solver tolerances cannot accumulate into a collision.

    Parameters
    ----------
    required
        ``(E,)`` true required centre distances.
    horizon
        ``N``.
    geometry
        Row geometry from the rules.
    reach
        Distance a neighbour can travel in one sample (missing slots), m; per slot
        through :meth:`set_reach`.
    margin
        Added to ``required`` in the QP rows, m.
    stage_one_rule_for_obstacles
        Apply ``stage-one-override`` to obstacle slots too (off for the
        paper's literal mode, which has no guarantee).
    deviation
        ``(alpha_max, beta_max)`` of :func:`sqpmpc.problem.margins.row_deviation` (robots
        with velocity states), or ``None``. With it the shared slots' hyperplane and
        check come from ``required + shared_margin`` (the solver's margin, the same in
        both robots) and each row of this robot keeps :attr:`own_margin` more:
        ``alpha_max + max(0, beta_max - h0)``, ``h0`` its current height above the
        check line (:mod:`sqpmpc.problem.plant`, "Where the robot stands decides the
        margin"); the obstacle and missing slots keep ``margin``.
    shared_margin
        See ``deviation``.
    """

    def __init__(self, required: np.ndarray, horizon: int, geometry: RowGeometry,
                 reach: float = 0.0, margin: float = 0.0,
                 stage_one_rule_for_obstacles: bool = True, recovery: float = -1.0,
                 deviation: tuple[float, float] | None = None,
                 shared_margin: float = 0.0) -> None:
        self.deviation = None if deviation is None else (float(deviation[0]),
                                                         float(deviation[1]))
        #: ``(E,)`` the margin this robot's shared rows keep beyond the check line
        #: (``deviation``; without it half the margin), m
        self.own_margin = np.full(np.asarray(required).size, 0.5 * float(margin))
        self._shared_margin = float(shared_margin)
        self._steady = 0.0 if deviation is None else float(largest_deviation(*self.deviation))
        #: tolerance of the ``overlap-recovery`` rule, m (negative: off)
        self.recovery = float(recovery)
        self.safe_distance = np.asarray(required, dtype=float)
        self.required = self.safe_distance + float(margin)
        E = self.required.size
        self.horizon = horizon
        self.geometry = geometry
        self.reach = float(reach)
        #: ``(E,)`` each slot's one-sample reach (missing slots; :meth:`set_reach`), m
        self.slot_reach = np.full(np.asarray(required).size, self.reach)
        self.stage_one_rule_for_obstacles = stage_one_rule_for_obstacles
        self.kind = np.zeros(E, dtype=np.int8)
        self.obstacles = np.zeros((E, horizon, 2))
        self.fixed_normals = np.zeros((E, horizon, 2))
        self.fixed_rhs = np.full((E, horizon), -np.inf)
        self.check_normals = np.zeros((E, 2))
        self.check_rhs = np.full(E, -np.inf)
        self.current_self = np.zeros(2)
        self.current_others = np.zeros((E, 2))
        self.touching = np.zeros(E, dtype=np.bool_)
        self.stage_one_overrides = 0
        self._shared_overrides = 0
        self._shared_mask = np.zeros(E, dtype=np.bool_)
        self._any_shared = self._any_obstacle = self._any_missing = False
        self._avoid = np.zeros(E, dtype=np.bool_)
        self._inside = np.zeros(E, dtype=np.bool_)  # scratch of the recovery check
        self._kinds_key = b""
        self._margin = float(margin)
        self.unslotted = np.zeros((0, 2))
        self.unslotted_distance = np.zeros(0)
        self._unslotted_keep = np.zeros(0)
        #: ``(E,)`` extra distance of obstacle and missing rows for plans that are late
        #: (:meth:`set_age_margins`); the first-stage check does not use it
        self.age_margin = np.zeros(E)
        self._aged = False

    def set_age_margins(self, margins: np.ndarray, aged: bool | None = None) -> None:
        """Per slot, distance added to the obstacle and missing rows (not to the check).

        A neighbour whose newest plan is ``a`` samples old has re-planned ``a - 1``
        times unseen: :class:`sqpmpc.control.decentralized.DecentralizedController` asks
        for ``v_max Ts (a - 1)`` more room, so that its rows give way earlier.
        ``aged``: whether some margin is positive, when the caller knows (else tested).
        """
        self.age_margin = np.asarray(margins, dtype=float)
        self._aged = bool((self.age_margin > 0.0).any()) if aged is None else bool(aged)

    def set_reach(self, reach: np.ndarray | None = None) -> None:
        """Per slot, how far its neighbour can travel in one sample ``(E,)``, m (``None``:
        :attr:`reach` for every slot): the ``missing-neighbour-reach`` row and check keep
        the distance plus it. Less than :attr:`reach` only for a neighbour whose motion
        is known to be bounded (a departed robot braked by its plant:
        :meth:`sqpmpc.control.decentralized.DecentralizedController.predict_neighbours`)."""
        if reach is None:
            self.slot_reach[:] = self.reach
        else:
            self.slot_reach[:] = reach

    def set_required(self, required: np.ndarray) -> None:
        """True required distances ``(E,)`` per slot (slots reassigned to other neighbours)."""
        self.safe_distance = np.asarray(required, dtype=float)
        self.required = self.safe_distance + self._margin

    def set_unslotted(self, positions: np.ndarray, required: np.ndarray) -> None:
        """Neighbours within reach that got no slot: current positions ``(U, 2)``, distances.

        The first-stage check keeps ``required + reach`` from each along the
        whole segment, or accepts standing still (as for a missing neighbour):
        whatever such a neighbour does within its bounds, the pair keeps its
        distance over the sample.
        """
        self.unslotted = np.ascontiguousarray(positions, dtype=float).reshape(-1, 2)
        self.unslotted_distance = np.asarray(required, dtype=float)
        self._unslotted_keep = self.unslotted_distance + self.reach

    def set_sample(self, current_self: np.ndarray, current_others: np.ndarray,
                   own_prediction: np.ndarray, other_predictions: np.ndarray,
                   kinds: np.ndarray) -> None:
        r"""Data of one sample.

        Parameters
        ----------
        current_self, current_others
            Measured positions ``(2,)`` and ``(E, 2)``.
        own_prediction
            ``(E, N, 2+)``: per slot, this robot's positions of stages 1..N as
            *published* (its plan of the pair's common sample, shifted),
            identical to what that neighbour uses; ``(N, 2+)``: the same for
            every slot.
        other_predictions
            ``(E, N, 2+)``: neighbours' positions for stages 1..N (shared
            slots: from their plans of the pair's common sample).
        kinds
            ``(E,)`` slot kinds (:data:`SHARED`, ...).
        """
        key = kinds.tobytes()
        if key != self._kinds_key:  # the slot kinds rarely change: masks only then
            self._kinds_key = key
            self.kind = kinds.copy()
            np.equal(kinds, SHARED, out=self._shared_mask)
            self._any_shared = bool(self._shared_mask.any())
            self._any_obstacle = bool((kinds == OBSTACLE).any())
            self._any_missing = bool((kinds == MISSING).any())
            self._avoid = (kinds == OBSTACLE) | (kinds == MISSING)
        self.current_self = np.ascontiguousarray(current_self, dtype=float)
        self.current_others = np.ascontiguousarray(current_others, dtype=float)
        self.obstacles = other_predictions
        if own_prediction.ndim == 2:
            own_prediction = np.repeat(own_prediction[None], kinds.shape[0], axis=0)
        g = self.geometry
        own = self.deviation is not None and self._any_shared
        self._shared_overrides = shared_rows(
            self.current_self, self.current_others, own_prediction, other_predictions,
            self._shared_mask,
            self.safe_distance + self._shared_margin if own else self.required,
            self.safe_distance, g.rotation,
            g.kernel_max_turn, self.fixed_normals, self.fixed_rhs, self.check_normals,
            self.check_rhs, self.touching)
        if own:
            self._keep_own_margin()
        if g.hold_touching:
            hold_touching_rows(self.current_self, self.touching, self.fixed_normals,
                               self.fixed_rhs)

    def _keep_own_margin(self) -> None:
        """The shared rows keep :attr:`own_margin` beyond what the kernel wrote; stage 1
        never asks for more than the current height (the row of a pair in the band)."""
        alpha, beta = self.deviation
        shared = self._shared_mask
        me = self.current_self
        h0 = np.maximum(self.check_normals[shared] @ me - self.check_rhs[shared], 0.0)
        # the smallest h1 of a passing segment, and at least its fixed point (the next stages)
        own = np.maximum(required_height(h0, alpha, beta), self._steady)
        self.own_margin[:] = 0.5 * self._shared_margin
        self.own_margin[shared] += self._steady
        now = self.fixed_normals[shared, 0] @ me
        first = self.fixed_rhs[shared, 0]
        self.fixed_rhs[shared, 1:] += self._steady
        self.fixed_rhs[shared, 0] = np.maximum(first, np.minimum(first + own, now))

    @property
    def needs_states(self) -> bool:
        """Whether :meth:`write_rows` reads the iterate (obstacle or missing slots)."""
        return self._any_obstacle or self._any_missing

    def write_rows(self, states: np.ndarray | None, A_out: np.ndarray,
                   lower_out: np.ndarray) -> None:
        """Rows at the own iterate ``states (1, N+1, 3)`` into ``(1, E, N, 2)``, ``(1, E, N)``.

        ``states`` may be ``None`` when :attr:`needs_states` is false.
        """
        A_out[0] = self.fixed_normals
        lower_out[0] = self.fixed_rhs
        overrides = self._shared_overrides
        if self._any_obstacle or self._any_missing:
            overrides += self._avoid_rows(states[0, 1:], A_out[0], lower_out[0])
        self.stage_one_overrides = overrides

    def _avoid_rows(self, own: np.ndarray, normals: np.ndarray, rhs: np.ndarray) -> int:
        """Obstacle and missing slots, relinearized at the own stages 1..N ``own (N, 2+)``."""
        required = self.required + self.age_margin if self._aged else self.required
        return obstacle_rows(self.current_self, self.current_others, own, self.obstacles,
                             self.kind, required, self.slot_reach, self.geometry.rotation,
                             self.stage_one_rule_for_obstacles, normals, rhs)

    def inside(self) -> np.ndarray:
        """``(E,)`` shared slots whose pair is inside its true distance now (a push, a slip):
        the ``overlap-recovery`` rule checks them against the current mid-line alone."""
        inside = np.zeros(self.kind.shape[0], dtype=np.bool_)
        inside_pairs(self.current_self, self.current_others, self._shared_mask,
                     self.safe_distance, inside)
        return inside

    def first_stage_safe(self, position: np.ndarray, tolerance: float = 1e-12,
                         alpha: float = 0.0, beta: float = 0.0) -> bool:
        r"""Whether this robot's next position ``(2,)`` keeps every true distance.

        Shared slots: the check of the class notes; the current position also
        satisfies it and a half-plane is convex, so the whole straight segment
        does; a true path within :math:`\alpha s + \beta s(1-s)` of the segment
        (:func:`sqpmpc.problem.plant.path_deviation`) is checked exactly
        (:func:`sqpmpc.kernels.collision.halfplanes_hold_path`). Obstacle slots:
        the true distance to the neighbour's predicted stage 1. Missing slots
        and neighbours within reach without a slot: the true distance plus the
        neighbour's reach, along the whole path, or standing still.
        """
        p = position
        x0, y0 = self.current_self.tolist()
        x1, y1 = float(p[0]), float(p[1])
        if self._any_shared:
            normals, rhs = self.check_normals, self.check_rhs
            if self.recovery >= 0.0 and inside_pairs(self.current_self, self.current_others,
                                                     self._shared_mask, self.safe_distance,
                                                     self._inside):
                inside = self._inside
                # overlap-recovery: no closer to the mid-line than now
                if not halfplanes_hold_path(
                        np.ascontiguousarray(normals[inside]), rhs[inside], x0, y0,
                        x1, y1, 0.0, 0.0, self.recovery):
                    return False
                normals = np.ascontiguousarray(normals[~inside])
                rhs = rhs[~inside]
            if not halfplanes_hold_path(normals, rhs, x0, y0, x1, y1, alpha, beta, tolerance):
                return False
        if self._any_obstacle:
            obst = self.kind == OBSTACLE
            d = p - self.obstacles[obst, 0, :2]
            if (np.hypot(d[:, 0], d[:, 1]) < self.safe_distance[obst] - tolerance).any():
                return False
        if not (self._any_missing or self.unslotted.shape[0]):
            return True
        moved = math.hypot(x1 - x0, y1 - y0) > 1e-12
        growth = alpha + max(beta, 0.0)
        if self._any_missing and moved:
            missing = self.kind == MISSING
            if not segment_keeps_distance(
                    x0, y0, x1, y1, np.ascontiguousarray(self.current_others[missing]),
                    self.safe_distance[missing] + self.slot_reach[missing], tolerance,
                    growth):
                return False
        if self.unslotted.shape[0] and moved and not segment_keeps_distance(
                x0, y0, x1, y1, self.unslotted, self._unslotted_keep, tolerance, growth):
            return False
        return True
