r"""Deadlock resolution: a right-hand detour rule for robots blocked by a neighbour.

In symmetric encounters (head-on pairs, antipodal swaps, paths crossing at
one point at one time) local NMPC has standoff equilibria: every robot is
stopped in front of a neighbour, each individually optimal given the
others. Tilting the collision hyperplanes does not always leave them, because
the linearized unicycle at rest cannot see that turning opens a way.

The rule, applied by every robot alike from measured positions only:

- a robot is *blocked* when its last applied speed is below ``speed`` and a
  neighbour closer than its required distance plus ``reach`` lies within
  ``cone`` of the direction to its stage-N reference, which is farther than
  ``reach``;
- after ``patience`` consecutive blocked samples (``patience_centralized`` for
  the centralized controller, whose joint optimization resolves most
  encounters itself, so the rule is its last resort) it takes a *detour*: for
  ``hold`` samples (renewed while it stays blocked) its reference on every
  stage is the point at distance ``radius`` from the blocker, rotated by
  ``angle`` to the right of the direction from the blocker to itself
  (clockwise). Two robots doing so circle each other clockwise, i.e. pass on
  their right, the usual traffic rule; the collision constraints are untouched,
  so safety does not depend on the rule.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DetourRule", "DetourSettings"]


@dataclass(frozen=True)
class DetourSettings:
    """Parameters of :class:`DetourRule` (see the module docstring)."""

    enabled: bool = True
    speed: float = 0.05
    reach: float = 0.3
    cone: float = float(np.deg2rad(75.0))
    patience: int = 2
    patience_centralized: int = 8
    hold: int = 6
    radius_factor: float = 2.0
    angle: float = float(np.deg2rad(60.0))


class DetourRule:
    """Per-robot detour state for ``m`` own robots among ``n``.

    Parameters
    ----------
    own
        ``(m,)`` indices of the own robots in the scenario.
    required
        ``(n, n)`` required centre distances.
    settings
        Rule parameters.
    patience
        Blocked samples before a detour starts (``settings.patience`` if ``None``).
    """

    def __init__(self, own: np.ndarray, required: np.ndarray, settings: DetourSettings,
                 patience: int | None = None):
        self.own = np.asarray(own, dtype=np.int64)
        self.patience = settings.patience if patience is None else int(patience)
        self.required = np.asarray(required, dtype=float)
        self.settings = settings
        m = self.own.size
        self.blocked_for = np.zeros(m, dtype=np.int64)
        self.active_for = np.zeros(m, dtype=np.int64)
        self.blocker = np.full(m, -1, dtype=np.int64)
        self.activations = 0
        self._rows = np.arange(m)
        self._own_required = self.required[self.own]
        self._cos_cone = np.cos(settings.cone)

    def apply(self, positions: np.ndarray, last_speed: np.ndarray,
              reference: np.ndarray) -> np.ndarray:
        """Return the references ``(m, N, 2)``, replaced by detour points where active.

        Parameters
        ----------
        positions
            ``(n, 2)`` measured positions of all robots.
        last_speed
            ``(m,)`` last applied speeds of the own robots.
        reference
            ``(m, N, 2)`` references of the own robots.
        """
        s = self.settings
        if not s.enabled or positions.shape[0] < 2:
            return reference
        slow = np.abs(last_speed) < s.speed
        if not np.count_nonzero(slow) and not np.count_nonzero(self.active_for):
            self.blocked_for[:] = 0  # hot path: nobody is a candidate or on a detour
            return reference
        p = positions[self.own]  # (m, 2)
        goal = reference[:, -1] - p
        goal_dist = np.hypot(goal[:, 0], goal[:, 1])
        candidates = slow & (goal_dist > s.reach)
        if not np.count_nonzero(candidates) and not np.count_nonzero(self.active_for):
            self.blocked_for[:] = 0
            return reference
        rel = positions[None, :, :] - p[:, None, :]  # (m, n, 2)
        dist = np.hypot(rel[..., 0], rel[..., 1])
        dist[self._rows, self.own] = np.inf
        along = rel[..., 0] * goal[:, None, 0] + rel[..., 1] * goal[:, None, 1]
        cos = along / np.maximum(dist * goal_dist[:, None], 1e-12)
        near = dist < self._own_required + s.reach
        blocking = near & (cos > self._cos_cone)
        blocked = candidates & blocking.any(axis=1)
        self.blocked_for = np.where(blocked, self.blocked_for + 1, 0)
        closest = np.argmin(np.where(blocking, dist, np.inf), axis=1)
        start = blocked & (self.blocked_for >= self.patience)
        self.activations += np.count_nonzero(start & (self.active_for == 0))
        self.blocker = np.where(start, closest, self.blocker)
        self.active_for = np.where(start, s.hold, np.maximum(self.active_for - 1, 0))
        active = self.active_for > 0
        if not np.count_nonzero(active):
            return reference
        out = reference.copy()
        for r in np.flatnonzero(active):
            b = self.blocker[r]
            away = p[r] - positions[b]
            away /= max(np.hypot(*away), 1e-12)
            c, sn = np.cos(s.angle), np.sin(s.angle)
            direction = np.array([c * away[0] - sn * away[1], sn * away[0] + c * away[1]])
            target = positions[b] + s.radius_factor * self.required[self.own[r], b] * direction
            out[r] = target
        return out
