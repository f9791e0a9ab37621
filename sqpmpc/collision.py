r"""Pairwise collision avoidance (paper eq. 5) as separating hyperplanes.

The distance constraint :math:`\|p_j - p_l\| \ge d_{jl}` is non-convex. Its
linearization at :math:`(\bar p_j, \bar p_l)` is the separating hyperplane

.. math::

    n^\top (p_j - p_l) \ge d_{jl}, \qquad n = \frac{\bar p_j - \bar p_l}{\|\bar p_j - \bar p_l\|},

which is also its first-order Taylor expansion, and an *inner* approximation:
:math:`\|p_j - p_l\| \ge n^\top(p_j - p_l)` for any unit :math:`n`, so a
satisfied row implies the true distance.

**Stage-1 rule.** The first predicted stage is a hard constraint. If the
Taylor normal of stage 1 does not keep the *current* configuration feasible,
:math:`n^\top(p_j(k) - p_l(k)) < d_{jl}`, the normal of the current positions
is used instead. Then stopping every robot (``v = 0``, exact for both
discretizations) always satisfies stage 1: the QP stays feasible and a safe
configuration stays safe (recursive feasibility at the sampling instants).

**Shared responsibility (decentralized).** Robots ``j`` and ``l`` build the
same hyperplane from the same exchanged predictions, each keeps half the
distance on its own side of the mid-line:
:math:`n^\top p_j \ge c + d/2` and :math:`-n^\top p_l \ge -c + d/2` imply
:math:`n^\top(p_j - p_l) \ge d`. With :math:`n` oriented from the other robot
to oneself, both robots evaluate the same formula. On stage 1 the offset
:math:`c` is clipped so that each robot's current position stays on its side.

**Symmetry breaking.** In exactly symmetric encounters the normals of two
robots heading at each other never turn and both stop (deadlock). A rotation
of every normal by a fixed angle :math:`\theta` (``keep_right_angle``),
applied by both robots alike, tilts the hyperplanes so that each robot is
pushed to its right and they pass each other.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "ExternalCollisionModel",
    "PairwiseCollisionModel",
    "limit_turning",
    "rotate",
    "segment_distances",
]

_EPS = 1e-9
_X_AXIS = np.array([1.0, 0.0])


def segment_distances(start: np.ndarray, end: np.ndarray) -> np.ndarray:
    r"""Smallest norm of :math:`r(s) = r_0 + s\,(r_1 - r_0)` over :math:`s \in [0, 1]`.

    For relative positions of two robots that move on straight segments at
    constant speed over a sample (the Euler model), this is their smallest
    distance during the sample; for a point and a segment, the point-segment
    distance. The minimizer is :math:`s^* = \mathrm{clip}(-r_0^\top \Delta r /
    \|\Delta r\|^2, 0, 1)`.

    Parameters
    ----------
    start, end
        ``(..., 2)`` relative positions at the start and the end of the sample.

    Returns
    -------
    np.ndarray
        ``(...)`` the smallest distances.
    """
    dr = end - start
    den = _dot(dr, dr)
    num = -_dot(start, dr)
    s = np.clip(np.divide(num, den, out=np.zeros_like(den), where=den > 0.0), 0.0, 1.0)
    closest = start + s[..., None] * dr
    return np.hypot(closest[..., 0], closest[..., 1])


def rotate(vectors: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    """Rotate 2-D vectors ``(..., 2)`` counter-clockwise by ``angle`` (rad, broadcast)."""
    if np.all(np.asarray(angle) == 0.0):
        return vectors
    c, s = np.cos(angle), np.sin(angle)
    return np.stack(
        (c * vectors[..., 0] - s * vectors[..., 1], s * vectors[..., 0] + c * vectors[..., 1]),
        axis=-1,
    )


def _rotation(angle: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Rotation by ``angle`` for :func:`_rotate`, ``None`` if every angle is 0.

    The rows ``(cos, sin)`` and ``(-sin, cos)`` of the rotation matrix, each
    shaped ``angle.shape + (2,)``.
    """
    if np.all(angle == 0.0):
        return None
    c, s = np.cos(angle), np.sin(angle)
    return np.stack((c, s), axis=-1), np.stack((-s, c), axis=-1)


def _rotate(vectors: np.ndarray, rotation: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """:func:`rotate` with a precomputed :func:`_rotation` (the same values).

    ``x (c, s) + y (-s, c)`` equals :func:`rotate`'s ``(c x - s y, s x + c y)``
    exactly: products commute and adding a negated product is subtracting it.
    """
    if rotation is None:
        return vectors
    first, second = rotation
    return vectors[..., :1] * first + vectors[..., 1:] * second


def _all(mask: np.ndarray) -> bool:
    """``mask.all()`` for the small masks of the hot path (a fraction of the call overhead)."""
    return np.count_nonzero(mask) == mask.size


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products of 2-D vectors ``(..., 2)`` (broadcast), as ``einsum("...i,...i")``."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


def _unit(d: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Unit vectors ``d / |d|`` of the differences ``d (..., 2)``.

    Where ``|d|`` is below 1e-9 m, ``fallback`` (unit vectors; ``d``'s shape must
    dominate its shape) is used.
    """
    dist = np.hypot(d[..., 0], d[..., 1])
    safe = dist > _EPS
    if _all(safe):  # hot path: no coinciding points
        return d / dist[..., None]
    return np.where(safe[..., None], d / np.where(safe, dist, 1.0)[..., None], fallback)


def limit_turning(n0: np.ndarray, normals: np.ndarray, max_turn: float) -> np.ndarray:
    r"""Limit how far a pair's normal turns from one stage to the next.

    Predictions sampled every :math:`T_s` can put two robots on opposite sides
    at consecutive stages although they would pass *through* each other in
    between (tunnelling); a plan built on such hyperplanes waits at stage 1 and
    jumps at stage 2, forever. A normal that turns by more than ``max_turn``
    from the previous stage's (stage 0: the current relative direction ``n0``)
    is replaced by the previous one turned by ``max_turn`` towards it
    (counter-clockwise when exactly opposite). Negating both normals of a pair
    commutes with this, so both robots compute the same hyperplanes.

    Parameters
    ----------
    n0
        ``(..., 2)`` unit normals of the current positions.
    normals
        ``(..., N, 2)`` unit normals of stages 1..N.
    max_turn
        Largest rotation between consecutive stages, rad (``>= pi`` disables).
    """
    if max_turn >= np.pi:
        return normals
    cos_max = np.cos(max_turn)
    # common case: no raw turn exceeds the limit, so none is clamped (hot path)
    if n0.shape[:-1] != normals.shape[:-2]:
        n0 = np.broadcast_to(n0, normals.shape[:-2] + n0.shape[-1:])
    previous = np.concatenate((n0[..., None, :], normals[..., :-1, :]), axis=-2)
    if _all(_dot(previous, normals) >= cos_max):
        return normals
    out = normals.copy()
    prev = n0
    for i in range(out.shape[-2]):
        cur = out[..., i, :]
        dot = np.einsum("...i,...i->...", prev, cur)
        cross = prev[..., 0] * cur[..., 1] - prev[..., 1] * cur[..., 0]
        turned = rotate(prev, np.where(cross < 0.0, -max_turn, max_turn))
        cur = np.where((dot < cos_max)[..., None], turned, cur)
        out[..., i, :] = cur
        prev = cur
    return out


def _pair_normals(
    gap_now: np.ndarray, pred_gap: np.ndarray, max_turn: float,
    rotation: tuple[np.ndarray, np.ndarray] | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Current normals ``(P, 2)`` and the stage normals ``(P, N, 2)`` of pairs.

    ``gap_now`` and ``pred_gap`` are the current and predicted offsets (this
    robot minus the other). The stage normals turn at most ``max_turn`` per
    stage and are rotated by ``rotation`` (see :func:`_rotation`).
    """
    n0 = _unit(gap_now, _X_AXIS)
    n = _unit(pred_gap, n0[..., None, :])
    return n0, _rotate(limit_turning(n0, n, max_turn), rotation)


def _stage_one(
    n: np.ndarray, n_now: np.ndarray, gap_now: np.ndarray, required: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """Apply the stage-1 rule to the stage normals ``n (P, N, 2)`` in place.

    ``n_now`` are the unit normals of the current positions, ``gap_now`` the
    current offsets (this robot minus the other). Returns the stage-1 normals
    ``(P, 2)``, their projected current gaps ``(P,)`` and the number of
    overridden rows.
    """
    n1 = n[:, 0]
    gap = _dot(n1, gap_now)
    keeps = gap >= required
    if _all(keeps):  # hot path: every Taylor normal keeps the current configuration
        return n1, gap, 0
    n1 = np.where(keeps[:, None], n1, n_now)
    n[:, 0] = n1
    return n1, _dot(n1, gap_now), int(keeps.size - np.count_nonzero(keeps))


class PairwiseCollisionModel:
    r"""Internal pair rows of the centralized QP (both robots are variables).

    Parameters
    ----------
    pairs
        ``(P, 2)`` local robot indices.
    required
        ``(P,)`` required centre distances :math:`(d_j + d_l)/2` plus the margin.
    keep_right_angle
        Symmetry-breaking rotation of the normals (rad), a scalar or one angle
        per stage ``(N,)``.
    max_turn
        Largest turn of a normal between consecutive stages (:func:`limit_turning`).
    """

    def __init__(self, pairs: np.ndarray, required: np.ndarray,
                 keep_right_angle: float | np.ndarray = 0.0, max_turn: float = 0.6):
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        self.required = np.asarray(required, dtype=float)
        self.keep_right_angle = np.asarray(keep_right_angle, dtype=float)
        self.max_turn = float(max_turn)
        self.current_positions: np.ndarray | None = None
        self.stage_one_overrides = 0
        self._rotation = _rotation(self.keep_right_angle)

    def set_current_positions(self, positions: np.ndarray) -> None:
        """Measured positions ``(m, 2)`` used by the stage-1 rule."""
        self.current_positions = np.asarray(positions, dtype=float)

    def rows(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r"""Normals ``(P, N, 2)`` and right-hand sides ``(P, N)`` at linearization ``states``.

        ``states`` is ``(m, N+1, 3)``; rows concern stages 1..N.
        """
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        now = self.current_positions
        gap_now = now[a] - now[b]
        pred = states[:, 1:, :2]
        n0, n = _pair_normals(gap_now, pred[a] - pred[b], self.max_turn, self._rotation)
        _, gap, self.stage_one_overrides = _stage_one(n, n0, gap_now, self.required)
        rhs = np.empty(n.shape[:2])
        rhs[:] = self.required[:, None]
        # never ask stage 1 for more than the current configuration has (margin included)
        np.minimum(self.required, gap, out=rhs[:, 0])
        return n, rhs


class ExternalCollisionModel:
    r"""Rows of one robot against neighbours whose predictions are data.

    Each slot ``e`` is one of:

    - ``"shared"``: fixed hyperplane from the exchanged predictions of both
      robots, half the distance each (linear constraint);
    - ``"obstacle"``: the neighbour's prediction is a moving obstacle and the
      full distance is kept, relinearized at the own iterate (the paper's literal
      scheme, and the fallback for a neighbour whose plan is missing);
    - ``"missing"``: a neighbour in the shared scheme whose plan did not
      arrive. Stages 2..N treat its extrapolated prediction as an obstacle;
      stage 1 must be safe whatever it does: if the current distance allows,
      keep :math:`d + r` from its current position, :math:`r = T_s v_{max}`
      its reach in one sample; otherwise do not approach it (and the safety
      check accepts only standing still, which its own shared constraint,
      clipped to our current position, keeps safe);
    - ``"off"``: no constraint.

    **Touching pairs.** Inside the margin (projected gap below the required
    distance plus margin) stage 1 only forbids approaching along :math:`n_1`.
    A unicycle whose heading points a hair inwards then cannot move at stage
    1, while stage 2's hyperplane, built from predictions in which the pair
    slides apart, lets it move: the plan says "wait, then go" every sample, a
    standoff (measured: a touching pair of swap-6 stays 3.15 m from its goals).
    Such pairs therefore keep the stage-1 row on stage 2 as well (soft, like
    every later stage); the plan turns first, then slides past.

    **Safety check of the first stage** (:meth:`first_stage_safe`). The QP
    rows carry the margin; the check accepts a position that keeps the *true*
    distance whatever the neighbour does within its own rows. For a shared slot
    with common normal :math:`n_1`, current projected gap
    :math:`g = n_1^\top(p_j(k) - p_l(k))` and true distance :math:`D`:
    if :math:`g \ge D + \text{margin}` both robots use the same mid-line
    :math:`c` and each must keep :math:`n_1^\top p \ge c + D/2`; otherwise
    (inside the margin, where the QP row only forbids approaching) each may
    give up at most :math:`\max(0, g - D)/2`, measured from the common current
    mid-line. Either way the two accepted positions keep
    :math:`n_1^\top(p_j - p_l) \ge \min(D, g)`: solver tolerances cannot
    accumulate into a collision over many samples.

    Parameters
    ----------
    required
        ``(E,)`` true required centre distances.
    horizon
        ``N``.
    keep_right_angle
        Symmetry-breaking rotation of the normals (rad).
    reach
        Distance a neighbour can travel in one sample (``"missing"`` slots), m.
    max_turn
        Largest turn of a normal between consecutive stages (:func:`limit_turning`).
    margin
        Added to ``required`` in the QP rows, m.
    """

    def __init__(self, required: np.ndarray, horizon: int,
                 keep_right_angle: float | np.ndarray = 0.0, reach: float = 0.0,
                 max_turn: float = 0.6, margin: float = 0.0):
        self.safe_distance = np.asarray(required, dtype=float)
        self.required = self.safe_distance + float(margin)
        E = self.required.size
        self.horizon = horizon
        self.reach = float(reach)
        self.keep_right_angle = np.asarray(keep_right_angle, dtype=float)
        self.max_turn = float(max_turn)
        self.obstacles = np.zeros((E, horizon, 2))
        self.fixed_normals = np.zeros((E, horizon, 2))
        self.fixed_rhs = np.full((E, horizon), -np.inf)
        self.current_self = np.zeros(2)
        self.current_others = np.zeros((E, 2))
        self.stage_one_rule_for_obstacles = True
        self._shared_overrides = 0
        self.stage_one_overrides = 0
        self._rotation = _rotation(self.keep_right_angle)
        self._half_required = 0.5 * self.required
        self._kinds: tuple[str, ...] | None = None
        self._set_kinds(["off"] * E)
        # stage-1 normals and bounds of the shared slots, for first_stage_safe
        self._stage_one_normals = np.zeros((0, 2))
        self._stage_one_rhs = np.zeros(0)

    def _set_kinds(self, kinds: list[str]) -> None:
        """Slot kinds and their masks (recomputed only when the kinds change)."""
        key = tuple(kinds)
        if key == self._kinds:
            return
        self._kinds = key
        self.kind = np.array(kinds, dtype=object)
        self._shared = self.kind == "shared"
        self._obstacle = self.kind == "obstacle"
        self._missing = self.kind == "missing"
        self._avoid = self._obstacle | self._missing
        self._any_shared = bool(self._shared.any())
        self._all_shared = bool(self._shared.all())
        self._any_obstacle = bool(self._obstacle.any())
        self._any_missing = bool(self._missing.any())
        self._any_avoid = bool(self._avoid.any())

    def set_sample(
        self,
        current_self: np.ndarray,
        current_others: np.ndarray,
        own_prediction: np.ndarray,
        other_predictions: np.ndarray,
        kinds: list[str],
    ) -> None:
        r"""Data of one sample.

        Parameters
        ----------
        current_self, current_others
            Measured positions ``(2,)`` and ``(E, 2)``.
        own_prediction
            ``(N, 2)``: this robot's positions of stages 1..N as *published*
            (its previous plan shifted), identical to what the neighbours use.
        other_predictions
            ``(E, N, 2)``: neighbours' positions for stages 1..N.
        kinds
            Slot kinds, ``"shared"``, ``"obstacle"`` or ``"off"``.
        """
        self._set_kinds(kinds)
        self.current_self = me = np.asarray(current_self, dtype=float)
        self.current_others = np.asarray(current_others, dtype=float)
        self.obstacles = np.asarray(other_predictions, dtype=float)
        self._shared_overrides = 0
        E, N = self.required.size, self.horizon
        if not self._any_shared:
            self.fixed_rhs = np.full((E, N), -np.inf)
            self.fixed_normals = np.zeros((E, N, 2))
            self._stage_one_normals = np.zeros((0, 2))
            self._stage_one_rhs = np.zeros(0)
            return
        # every slot shared (the usual case): plain views instead of masked copies
        sel = slice(None) if self._all_shared else self._shared
        own = np.asarray(own_prediction, dtype=float)
        if own.ndim == 3:
            own = own[sel]
        oth = self.obstacles[sel]
        d = self.required[sel]
        half = self._half_required[sel]
        now_o = self.current_others[sel]
        gap_now = me - now_o
        n0, n = _pair_normals(gap_now, own - oth, self.max_turn, self._rotation)
        n1, gap, self._shared_overrides = _stage_one(n, n0, gap_now, d)
        c = _dot(n, 0.5 * (own + oth))
        lo = _dot(n1, now_o) + half
        n1_me = _dot(n1, me)
        hi = n1_me - half
        c[:, 0] = np.clip(c[:, 0], lo, np.maximum(lo, hi))
        rhs = c + half[:, None]
        # within the margin both robots keep at least their current side (stopping stays
        # feasible and the pair keeps its current gap, which is safe)
        rhs[:, 0] = np.minimum(rhs[:, 0], n1_me)
        # touching (inside the margin): stage 2 keeps the stage-1 row too (class notes)
        touching = gap < d
        if N > 1 and touching.any():
            n[touching, 1] = n1[touching]
            rhs[touching, 1] = n1_me[touching]
        # first-stage check on the true distance (see the class notes)
        D = self.safe_distance[sel]
        mid = _dot(n1, 0.5 * (me + now_o))
        if self._all_shared:
            self.fixed_normals, self.fixed_rhs = n, rhs
        else:
            self.fixed_normals = np.zeros((E, N, 2))
            self.fixed_normals[sel] = n
            self.fixed_rhs = np.full((E, N), -np.inf)
            self.fixed_rhs[sel] = rhs
        self._stage_one_normals = np.ascontiguousarray(n[:, 0])
        self._stage_one_rhs = np.where(gap >= d, c[:, 0] + 0.5 * D,
                                       mid + 0.5 * np.minimum(D, gap))

    def rows(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normals ``(1, E, N, 2)`` and rhs ``(1, E, N)`` at the own iterate ``(1, N+1, 3)``."""
        normals = self.fixed_normals.copy()
        rhs = self.fixed_rhs.copy()
        overrides = self._shared_overrides
        if self._any_avoid:
            obst = self._avoid
            me = self.current_self
            own = states[0, 1:, :2]
            o = self.obstacles[obst]
            gap_now = me - self.current_others[obst]
            n0 = _unit(gap_now, _X_AXIS)
            n = _rotate(_unit(own[None] - o, n0[:, None, :]), self._rotation)
            if self.stage_one_rule_for_obstacles:
                overrides += _stage_one(n, n0, gap_now, self.required[obst])[2]
            normals[obst] = n
            rhs[obst] = _dot(n, o) + self.required[obst][:, None]
            if self._any_missing:
                missing = self._missing
                others = self.current_others[missing]
                gap_now = me - others
                n0 = _unit(gap_now, _X_AXIS)
                keep = self.required[missing] + self.reach
                normals[missing, 0] = n0
                rhs[missing, 0] = np.where(_dot(n0, gap_now) >= keep, _dot(n0, others) + keep,
                                           _dot(n0, me))
        self.stage_one_overrides = overrides
        return normals[None], rhs[None]

    def first_stage_safe(self, position: np.ndarray, tolerance: float = 1e-12) -> bool:
        """Whether this robot's next position ``(2,)`` keeps every true distance.

        Shared slots: the check of the class notes; as the current position
        also satisfies it and the half-plane is convex, the whole straight
        segment to the next position does, so the pair is separated during
        the sample too. Obstacle slots: the true distance to the neighbour's
        predicted stage 1. Missing slots: the true distance plus the
        neighbour's one-sample reach, from its current position to every point
        of this robot's segment, or standing still.
        """
        p = np.asarray(position, dtype=float)
        if self._any_shared and np.count_nonzero(
            self._stage_one_normals @ p < self._stage_one_rhs - tolerance
        ):
            return False
        if self._any_obstacle:
            obst = self._obstacle
            d = p - self.obstacles[obst, 0]
            if (np.hypot(d[:, 0], d[:, 1]) < self.safe_distance[obst] - tolerance).any():
                return False
        if self._any_missing and np.hypot(*(p - self.current_self)) > 1e-12:
            missing = self._missing
            others = self.current_others[missing]
            keep = self.safe_distance[missing] + self.reach
            if (segment_distances(self.current_self - others, p - others)
                    < keep - tolerance).any():
                return False
        return True
