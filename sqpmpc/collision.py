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
    "unit_normals",
]

_EPS = 1e-9


def rotate(vectors: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    """Rotate 2-D vectors ``(..., 2)`` counter-clockwise by ``angle`` (rad, broadcast)."""
    if np.all(np.asarray(angle) == 0.0):
        return vectors
    c, s = np.cos(angle), np.sin(angle)
    return np.stack(
        (c * vectors[..., 0] - s * vectors[..., 1], s * vectors[..., 0] + c * vectors[..., 1]),
        axis=-1,
    )


def unit_normals(
    p_from: np.ndarray, p_to: np.ndarray, fallback: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    r"""Unit vectors :math:`(p_{from} - p_{to}) / \|\cdot\|` and the distances.

    Where the points coincide (distance below 1e-9 m) ``fallback`` (broadcast to
    the same shape, unit vectors) is used.
    """
    d = p_from - p_to
    dist = np.hypot(d[..., 0], d[..., 1])
    safe = dist > _EPS
    n = np.where(safe[..., None], d / np.where(safe, dist, 1.0)[..., None], fallback)
    return n, dist


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
    first = np.einsum("...i,...i->...", n0, normals[..., 0, :])
    later = np.einsum("...ni,...ni->...n", normals[..., :-1, :], normals[..., 1:, :])
    if (first >= cos_max).all() and (later >= cos_max).all():
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
    now_self: np.ndarray, now_other: np.ndarray, pred_self: np.ndarray,
    pred_other: np.ndarray, max_turn: float, angle: np.ndarray | float,
) -> tuple[np.ndarray, np.ndarray]:
    """Current normals ``(..., 2)`` and the stage normals ``(..., N, 2)`` of pairs.

    The stage normals point from the other robot's to this robot's predicted
    positions, turn at most ``max_turn`` per stage and are rotated by ``angle``.
    """
    n0 = unit_normals(now_self, now_other, np.array([1.0, 0.0]))[0]
    n, _ = unit_normals(pred_self, pred_other, n0[..., None, :])
    return n0, rotate(limit_turning(n0, n, max_turn), angle)


def _stage_one(
    n1: np.ndarray, n_now: np.ndarray, gap_now: np.ndarray, required: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Apply the stage-1 rule; returns the normals and a mask of overridden rows.

    ``n_now`` are the unit normals of the current positions, ``gap_now`` the
    current offsets (this robot minus the other).
    """
    keeps = np.einsum("...i,...i->...", n1, gap_now) >= required
    return np.where(keeps[..., None], n1, n_now), ~keeps


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

    def set_current_positions(self, positions: np.ndarray) -> None:
        """Measured positions ``(m, 2)`` used by the stage-1 rule."""
        self.current_positions = np.asarray(positions, dtype=float)

    def rows(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r"""Normals ``(P, N, 2)`` and right-hand sides ``(P, N)`` at linearization ``states``.

        ``states`` is ``(m, N+1, 3)``; rows concern stages 1..N.
        """
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        now = self.current_positions
        n0, n = _pair_normals(now[a], now[b], states[a, 1:, :2], states[b, 1:, :2],
                              self.max_turn, self.keep_right_angle)
        n1, over = _stage_one(n[:, 0], n0, now[a] - now[b], self.required)
        n[:, 0] = n1
        self.stage_one_overrides = int(over.sum())
        rhs = np.broadcast_to(self.required[:, None], n.shape[:2]).copy()
        # never ask stage 1 for more than the current configuration has (margin included)
        rhs[:, 0] = np.minimum(rhs[:, 0], np.einsum("pi,pi->p", n1, now[a] - now[b]))
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
        self.kind = np.array(["off"] * E, dtype=object)
        self.obstacles = np.zeros((E, horizon, 2))
        self.fixed_normals = np.zeros((E, horizon, 2))
        self.fixed_rhs = np.full((E, horizon), -np.inf)
        self.safe_rhs = np.full(E, -np.inf)
        self.current_self = np.zeros(2)
        self.current_others = np.zeros((E, 2))
        self.stage_one_rule_for_obstacles = True
        self._shared_overrides = 0
        self.stage_one_overrides = 0

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
        self.kind = np.array(kinds, dtype=object)
        self.current_self = np.asarray(current_self, dtype=float)
        self.current_others = np.asarray(current_others, dtype=float)
        self.obstacles = np.asarray(other_predictions, dtype=float)
        shared = self.kind == "shared"
        self.fixed_rhs = np.full((self.required.size, self.horizon), -np.inf)
        self.fixed_normals = np.zeros((self.required.size, self.horizon, 2))
        self.safe_rhs = np.full(self.required.size, -np.inf)
        self._shared_overrides = 0
        if not np.any(shared):
            return
        own = np.broadcast_to(own_prediction, self.obstacles.shape)[shared]
        oth = self.obstacles[shared]
        d = self.required[shared]
        half = 0.5 * d
        now_o = self.current_others[shared]
        n0, n = _pair_normals(self.current_self, now_o, own, oth, self.max_turn,
                              self.keep_right_angle)
        n1, over = _stage_one(n[:, 0], n0, self.current_self - now_o, d)
        n[:, 0] = n1
        c = np.einsum("eni,eni->en", n, 0.5 * (own + oth))
        lo = np.einsum("ei,ei->e", n1, now_o) + half
        hi = np.einsum("ei,i->e", n1, self.current_self) - half
        c[:, 0] = np.clip(c[:, 0], lo, np.maximum(lo, hi))
        self.fixed_normals[shared] = n
        rhs = c + half[:, None]
        # within the margin both robots keep at least their current side (stopping stays
        # feasible and the pair keeps its current gap, which is safe)
        rhs[:, 0] = np.minimum(rhs[:, 0], np.einsum("ei,i->e", n1, self.current_self))
        self.fixed_rhs[shared] = rhs
        # first-stage check on the true distance (see the class notes)
        D = self.safe_distance[shared]
        gap = np.einsum("ei,ei->e", n1, self.current_self - now_o)
        mid = np.einsum("ei,ei->e", n1, 0.5 * (self.current_self + now_o))
        self.safe_rhs[shared] = np.where(gap >= d, c[:, 0] + 0.5 * D,
                                         mid + 0.5 * np.minimum(D, gap))
        self._shared_overrides = int(over.sum())

    def rows(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normals ``(1, E, N, 2)`` and rhs ``(1, E, N)`` at the own iterate ``(1, N+1, 3)``."""
        normals = self.fixed_normals.copy()
        rhs = self.fixed_rhs.copy()
        obst = (self.kind == "obstacle") | (self.kind == "missing")
        overrides = self._shared_overrides
        if np.any(obst):
            own = states[0, 1:, :2]
            o = self.obstacles[obst]
            n0 = unit_normals(self.current_self, self.current_others[obst],
                              np.array([1.0, 0.0]))[0]
            n, _ = unit_normals(own[None], o, n0[:, None, :])
            n = rotate(n, self.keep_right_angle)
            if self.stage_one_rule_for_obstacles:
                n1, over = _stage_one(n[:, 0], n0, self.current_self - self.current_others[obst],
                                      self.required[obst])
                n[:, 0] = n1
                overrides += int(over.sum())
            normals[obst] = n
            rhs[obst] = np.einsum("eni,eni->en", n, o) + self.required[obst][:, None]
            missing = self.kind == "missing"
            if np.any(missing):
                n0 = unit_normals(self.current_self, self.current_others[missing],
                                  np.array([1.0, 0.0]))[0]
                gap = np.einsum("ei,ei->e", n0, self.current_self - self.current_others[missing])
                keep = self.required[missing] + self.reach
                normals[missing, 0] = n0
                rhs[missing, 0] = np.where(
                    gap >= keep,
                    np.einsum("ei,ei->e", n0, self.current_others[missing]) + keep,
                    np.einsum("ei,i->e", n0, self.current_self),
                )
        self.stage_one_overrides = overrides
        return normals[None], rhs[None]

    def first_stage_safe(self, position: np.ndarray, tolerance: float = 1e-12) -> bool:
        """Whether this robot's next position ``(2,)`` keeps every true distance.

        Shared slots: the check of the class notes. Obstacle slots: the true
        distance to the neighbour's predicted stage 1. Missing slots: the true
        distance plus the neighbour's one-sample reach from its current
        position, or standing still.
        """
        p = np.asarray(position, dtype=float)
        shared = self.kind == "shared"
        if np.any(self.fixed_normals[shared, 0] @ p < self.safe_rhs[shared] - tolerance):
            return False
        obst = self.kind == "obstacle"
        if np.any(obst):
            d = p - self.obstacles[obst, 0]
            if np.any(np.hypot(d[:, 0], d[:, 1]) < self.safe_distance[obst] - tolerance):
                return False
        missing = self.kind == "missing"
        if np.any(missing) and np.hypot(*(p - self.current_self)) > 1e-12:
            d = p - self.current_others[missing]
            keep = self.safe_distance[missing] + self.reach
            if np.any(np.hypot(d[:, 0], d[:, 1]) < keep - tolerance):
                return False
        return True
