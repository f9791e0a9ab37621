r"""The ``roundabout`` rule: dense crowds are passed counter-clockwise, on the right.

Pairwise rules (``keep-right``, ``detour``) resolve encounters of a few
robots. When tens of robots head for the same region at once (an antipodal
swap of 16 to 64, a crossing of two streams), every robot's straight path
ends in one jam, and pairwise tilts only make it rotate slowly in place. The
classical cure for many vehicles whose paths cross is a *roundabout*: every
vehicle that meets a conflict zone circles it in the same sense and leaves it
where its own goal lies (Pallottino, Scordio, Bicchi and Frazzoli,
"Decentralized cooperative policy for conflict resolution in multivehicle
systems", IEEE T-RO 23(6), 2007, who give conditions under which such a
policy is safe and live for many vehicles; the traffic roundabout is its
everyday form). Here the
conflict zone is sensed, not given: each robot looks at the robots ahead of
it, and the same deterministic rule in every robot makes them all turn the
same way.

For an own robot at :math:`p` with goal :math:`g` (its stage-``N`` scenario
reference) farther than ``goal_distance``, the *crowd ahead* is the set
:math:`C` of other robots :math:`j` with

.. math::

    \|p_j - p\| \le \min(\text{sense}, \|g - p\|), \qquad
    \angle(p_j - p,\ g - p) \le \text{cone}, \qquad
    \angle(h_j,\ g - p) > \text{along},

with :math:`h_j` robot ``j``'s heading: a robot heading the way this one
goes is traffic, not a conflict (a formation moving together does not
circle itself). A robot within ``goal_distance`` of the point where its
reference comes to rest has arrived: it is an obstacle to pass (the other
rules and the rows handle it), not a flow to circle with.

When :math:`|C| \ge` ``min_crowd``, the crowd is the disc of centre
:math:`c = \operatorname{mean}_{j \in C} p_j` and radius
:math:`\rho = \max_{j \in C} (\|p_j - c\| + d_j)`, with :math:`d_j` the
required distance to robot ``j``. If the straight path to the goal crosses
that disc (the goal direction lies between the two tangents from :math:`p`),
the robot heads along the *right* tangent, which keeps the crowd on its left
(counter-clockwise around it); inside the disc it moves along the circle
around :math:`c`, counter-clockwise. Its references of stages 1..N become
the points :math:`p + i\,T_s\,v_\text{ref}\,u`, :math:`u` the chosen
direction and :math:`v_\text{ref}` = ``speed_fraction`` times the largest
speed. Once fewer than ``min_crowd`` robots are ahead (or the path clears the
disc), the robot tracks its goal again.

The rule only changes references: every collision row, the hard stage 1 and
the verification of the first input are untouched, so it chooses among safe
motions like the other rules.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numba
import numpy as np

from .errors import ProblemError
from .rules import Rule, RuleContext, RuleInstance, SampleView, check_positive

__all__ = ["Roundabout", "roundabout_directions", "warm_up_roundabout"]

_jit = numba.njit(cache=True, nogil=True)


@_jit
def roundabout_directions(positions: np.ndarray, headings: np.ndarray,
                          rest_goals: np.ndarray, own: np.ndarray, goals: np.ndarray,
                          required: np.ndarray, sense: float, cos_cone: float,
                          cos_along: float, min_crowd: int, goal_distance: float,
                          directions: np.ndarray) -> int:
    """The roundabout direction of every own robot, or zeros where the rule is idle.

    Parameters
    ----------
    positions, headings
        ``(n, 2)`` positions and ``(n,)`` headings of all robots.
    rest_goals
        ``(n, 2)`` where each robot's reference comes to rest at the end of the
        scenario (NaN for references still moving then): a robot within
        ``goal_distance`` of it has arrived and is not part of a crowd.
    own
        ``(m,)`` indices of the own robots in ``positions``.
    goals
        ``(m, 2)`` the own robots' goals (stage-``N`` scenario references).
    required
        ``(m, n)`` required distances from the own robots to everyone.
    sense, cos_cone, cos_along, min_crowd, goal_distance
        See :class:`Roundabout` (``cos_cone`` and ``cos_along`` are the cosines
        of ``cone`` and ``along``).
    directions
        ``(m, 2)`` output: unit directions, or ``(0, 0)`` for robots that
        track their goal.

    Returns
    -------
    int
        How many own robots follow a roundabout direction.
    """
    n = positions.shape[0]
    member = np.zeros(n, dtype=np.bool_)
    active = 0
    for r in range(own.shape[0]):
        i = own[r]
        directions[r, 0] = 0.0
        directions[r, 1] = 0.0
        px, py = positions[i, 0], positions[i, 1]
        gx, gy = goals[r, 0] - px, goals[r, 1] - py
        goal_dist = math.hypot(gx, gy)
        if not goal_dist > goal_distance:
            continue
        ux, uy = gx / goal_dist, gy / goal_dist
        reach = min(sense, goal_dist)
        count = 0
        cx, cy = 0.0, 0.0
        for j in range(n):
            member[j] = False
            if j == i:
                continue
            rx, ry = positions[j, 0] - px, positions[j, 1] - py
            d = math.hypot(rx, ry)
            if d > reach or rx * ux + ry * uy < d * cos_cone:
                continue
            if math.cos(headings[j]) * ux + math.sin(headings[j]) * uy > cos_along:
                continue  # heading the way this robot goes: traffic, not a conflict
            if math.hypot(positions[j, 0] - rest_goals[j, 0],
                          positions[j, 1] - rest_goals[j, 1]) <= goal_distance:
                continue  # arrived: an obstacle to pass, not a flow to join
            member[j] = True
            count += 1
            cx += positions[j, 0]
            cy += positions[j, 1]
        if count < min_crowd:
            continue
        cx /= count
        cy /= count
        rho = 0.0
        for j in range(n):
            if member[j]:
                rho = max(rho, math.hypot(positions[j, 0] - cx, positions[j, 1] - cy)
                          + required[r, j])
        wx, wy = cx - px, cy - py
        w = math.hypot(wx, wy)
        if w > rho:
            wx, wy = wx / w, wy / w
            beta = math.asin(rho / w)
            gamma = math.atan2(wx * uy - wy * ux, wx * ux + wy * uy)
            if gamma <= -beta or gamma >= beta:
                continue  # the straight path clears the crowd
            c, s = math.cos(beta), math.sin(beta)
            directions[r, 0], directions[r, 1] = c * wx + s * wy, -s * wx + c * wy
        else:  # inside the crowd: counter-clockwise around its centre
            if w > 1e-9:
                wx, wy = wx / w, wy / w
            else:
                wx, wy = ux, uy
            directions[r, 0], directions[r, 1] = wy, -wx
        active += 1
    return active


class _RoundaboutInstance(RuleInstance):
    rule: Roundabout
    counter_names = ("roundabout_samples",)

    def __init__(self, rule: Roundabout, context: RuleContext) -> None:
        super().__init__(rule, context)
        self.required = np.ascontiguousarray(
            context.scenario.required_distances()[context.own])
        self.directions = np.zeros((context.own.size, 2))
        step = rule.speed_fraction * context.max_speed * context.sample_time
        self.offsets = step * np.arange(1, context.horizon + 1, dtype=float)
        self._cos_cone = math.cos(rule.cone)
        self._cos_along = math.cos(rule.along)
        self.references_changed()
        self._no_headings = np.zeros(context.scenario.n_robots)

    def references_changed(self) -> None:
        sc = self.context.scenario
        rest = np.hypot(*sc.reference_velocities(sc.t_end).T) == 0.0
        self.rest_goals = np.where(rest[:, None], sc.reference_positions(sc.t_end), np.nan)

    def shape_references(self, view: SampleView) -> None:
        r = self.rule
        if view.positions.shape[0] <= r.min_crowd:
            return
        if view.headings is None:  # every robot ahead counts (a cosine never exceeds 2)
            headings, cos_along = self._no_headings, 2.0
        else:
            headings, cos_along = view.headings, self._cos_along
        active = roundabout_directions(
            view.positions, headings, self.rest_goals, self.context.own,
            np.ascontiguousarray(view.scenario_references[:, -1]), self.required, r.sense,
            self._cos_cone, cos_along, r.min_crowd, r.goal_distance, self.directions)
        if not active:
            return
        self.counts["roundabout_samples"] += active
        out = view.references.copy()
        for k in np.flatnonzero(self.directions.any(axis=1)):
            out[k] = view.own_states[k, :2] + self.offsets[:, None] * self.directions[k]
        view.references = out


@dataclass(frozen=True)
class Roundabout(Rule):
    """Pass a crowd of at least ``min_crowd`` robots ahead counter-clockwise, on its right.

    See the module docstring for the rule; ``sense`` (m) is how far ahead a
    robot looks, ``cone`` (rad) the half-angle of "ahead", ``goal_distance``
    (m) the distance to the goal below which the rule is idle, ``along`` (rad)
    the angle within which a robot heading the way this one goes is traffic
    rather than a conflict (it does not count in the crowd), and
    ``speed_fraction`` the share of the largest speed the roundabout
    references move at.
    """

    name = "roundabout"
    summary = "a crowd of 4+ robots ahead is passed counter-clockwise along its right tangent"
    instance = _RoundaboutInstance
    min_crowd: int = 4
    sense: float = 3.0
    cone: float = float(np.deg2rad(60.0))
    along: float = float(np.deg2rad(45.0))
    goal_distance: float = 1.0
    speed_fraction: float = 1.0

    def __post_init__(self) -> None:
        check_positive(self, "min_crowd", "sense", "cone", "along", "goal_distance",
                       "speed_fraction")
        if not isinstance(self.min_crowd, numbers.Integral):
            raise ProblemError(f"rule 'roundabout': min_crowd must be an integer, "
                               f"got {self.min_crowd!r}")
        if self.cone >= np.pi / 2:
            raise ProblemError(f"rule 'roundabout': cone must be below pi/2, got {self.cone}")
        if self.along >= np.pi:
            raise ProblemError(f"rule 'roundabout': along must be below pi, got {self.along}")
        if self.speed_fraction > 1.0:
            raise ProblemError(f"rule 'roundabout': speed_fraction must be at most 1, "
                               f"got {self.speed_fraction}")


def warm_up_roundabout() -> None:
    """Compile or load the rule's kernel with the array layouts the rule passes."""
    roundabout_directions(np.zeros((3, 2)), np.zeros(3), np.full((3, 2), np.nan), np.arange(2),
                          np.ones((2, 2)), np.ones((2, 3)), 3.0, 0.5, 0.7, 4, 1.0,
                          np.zeros((2, 2)))
