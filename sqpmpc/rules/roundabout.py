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
distance the rows keep to robot ``j`` (the required distance plus their margin
for the plant, :meth:`~sqpmpc.rules.base.RuleContext.kept_distances`). If the
straight path to the goal crosses that disc (the goal direction lies between
the two tangents from :math:`p`), the robot heads along the *right* tangent,
which keeps the crowd on its left (counter-clockwise around it); inside the
disc it moves along the circle around :math:`c`, counter-clockwise. Its
references of stages 1..N become the points :math:`p + i\,T_s\,v_\text{ref}\,u`,
:math:`u` the chosen direction and :math:`v_\text{ref}` = ``speed_fraction``
times the largest speed. Once fewer than ``min_crowd`` robots are ahead (or
the path clears the disc), the robot tracks its goal again.

The defaults (a crowd of 4 within 3 m) leave swaps of 4 robots to the pairwise
rules (a four-way jam at the centre can stand 10 s) and can miss the head-on
pair of swap-6 whose crowd counts 3 (the four others circle, the pair stands
6.5 s face to face). A crowd of 3 within 2.5 m lets the small swaps flow: on
the maps benchmark (``benchmarks/maps.py``, 257 runs) the swaps' median
normalized makespan was 1.48 (1.62 with the defaults) and the crossings' 1.32,
but a 25-robot grid and a 32-robot warehouse were left stuck (every run
arrives with the defaults), so the defaults stay; swaps of 16-64 were slower
with it (their time goes into the dense centre and into stragglers the crowd
ahead keeps carrying sideways: a crowd that moves with the robot is never
rounded).

Leaving robots that the route or yield rule already steers to that rule (the
crowd's tangent knows no walls; it once led a warehouse robot off its route
against an arrived robot, where it stood) fixed that run but left a 64-robot
warehouse stuck that arrives without it; it was dropped.

**Rings.** A sensed crowd is found late (3 m ahead, when the jam has already
formed) and its disc moves with it. Where the straight ways of several
robots cross at about the same time (an antipodal swap: every way through the
centre), the conflict zone is known from the start, so the rule fixes it
then: at the first sample (and again after a reference changes) the ways
from the measured positions to the goals at rest are grouped by
:func:`sqpmpc.kernels.rings.ring_zones`: two ways *meet* where they cross
when both robots are within ``ring_window`` metres of the same distance from
that point and go different ways (more than ``along`` apart; opposite ways
on one line meet half-way); the meeting point with the most others within
``ring_cluster`` metres makes a zone of the robots meeting there, if they are
at least ``ring_crowd`` and come from all sides (the mean of their unit
directions is at most 0.5 long: a group meeting one robot head-on is left to
the crowd rule), centred at the mean of those meeting points. Its *ring*
has the radius :math:`\rho = \max(m\,s / 2\pi,
\rho_\min)` for :math:`m` members ``ring_spacing`` = :math:`s` apart, with
:math:`\rho_\min` the larger of twice the kept distance and the turning
radius at the reference speed (:math:`v_\text{ref}/\omega_\max`); a zone
whose ring would come closer than the kept distance to a member's start or
goal or to a pillar, and any zone in a map with walls (polygons: the route
rule knows them, a ring does not), is dropped. At every sample, a member
farther than ``goal_distance`` from its goal whose straight way still
crosses the ring, while at least ``ring_crowd - 1`` other members still have
to pass it (not arrived, inside the ring or with a way through it) and no
arrived robot stands in it, tracks references :math:`v_\text{ref} T_s`
apart along the ring's counter-clockwise tangent, around the ring and off it
towards the goal as soon as the straight way clears it
(:func:`sqpmpc.kernels.rings.ring_path`); otherwise the crowd rule above
applies. Every robot computes the same zones from the same measured
positions, so the decentralized robots agree on them.

On the maps benchmark's swaps (50 seeded runs of 4 to 64 robots,
decentralized) the rings took the median normalized makespan from 1.62 to
1.13 (swap-6 1.10, swap-64 1.35) and the crossings among pillars from 1.41
to 1.39, with every run arriving; the paper's scenarios (references that
never rest) have no ring and keep their costs. A first spacing of 0.55 m
packed eight robots on a ring they could not follow at full speed (swap-8
1.99); 0.7 m gives them room. A ring squeezed next to a pillar (radius 0.52 m)
once changed a 64-robot crossing enough that another robot was left standing
against a pillar elsewhere: hence the dropped zones without room.

**A crowd without room.** A ring spaces its members ``ring_spacing`` apart only
when the room around its centre allows the radius :math:`m\,s/2\pi`; an antipodal
swap's ring outgrows the swap's own circle from about 115 robots (its radius grows
with :math:`m`, the circle with :math:`\sqrt{m}`), and the ring cut to the circle
packed 256 robots 0.47 m apart on a ring they could not follow: 209/256 home, 258
brake fallbacks. The rules have no other motion that passes such a crowd, so
:func:`crowd_without_room` (the rings of the start, with the rule's own spacing:
no new threshold) makes the roadmap coordination the default for such scenarios
(:func:`sqpmpc.rules.registry.default_names`): 256/256 home.

The zones are found in about :math:`O(m \log m)` for :math:`m` meeting points
(:func:`sqpmpc.kernels.rings.ring_zones`: the same zones as counting every point
against every other, which cost 7.6 s per robot at the first sample of a
256-robot swap, 1.3-2.3 ms now; 66-86 ms and 1.2-1.5 ms for 256 random crossings;
checked against that plain count in ``tests/test_rule_roundabout_rings.py``).

The rule only changes references: every collision row, the hard stage 1 and
the verification of the first input are untouched, so it chooses among safe
motions like the other rules.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.kernels.rings import ring_busy, ring_path, ring_zones, segment_distance
from sqpmpc.kernels.rules import roundabout_directions
from sqpmpc.problem.references import PointReference
from sqpmpc.rules.base import (
    Contribution,
    Rule,
    RuleContext,
    RuleInstance,
    SampleView,
    check_positive,
    read_only,
)

__all__ = ["Rings", "Roundabout", "crowd_without_room", "find_rings", "ring_min_radius",
           "roundabout_directions"]

if TYPE_CHECKING:
    from sqpmpc.problem.scenario import Scenario



class _RoundaboutInstance(RuleInstance):
    rule: Roundabout
    hooks = ("references",)
    counter_names = ("roundabout_samples", "ring_samples")

    def __init__(self, rule: Roundabout, context: RuleContext) -> None:
        super().__init__(rule, context)
        self.required = np.ascontiguousarray(context.kept_distances())
        self.directions = np.zeros((context.own.size, 2))
        step = rule.speed_fraction * context.max_speed * context.sample_time
        self.offsets = step * np.arange(1, context.horizon + 1, dtype=float)
        self._cos_cone = math.cos(rule.cone)
        self._cos_along = math.cos(rule.along)
        self.step = step
        n = context.scenario.n_robots
        self.zone_of = np.full(n, -1, dtype=np.int64)
        self.centres, self.radii = np.zeros((0, 2)), np.zeros(0)  # of the zones
        self.zones_ready = False
        self.min_radius = ring_min_radius(rule, context.scenario, float(self.required.max()))
        self.references_changed()
        self._no_headings = read_only(np.zeros(n))

    def references_changed(self) -> None:
        sc = self.context.scenario
        rest = np.hypot(*sc.reference_velocities(sc.t_end).T) == 0.0
        self.rest_goals = np.where(rest[:, None], sc.reference_positions(sc.t_end), np.nan)
        self.zones_ready = False  # found again from the positions of the next sample

    def _find_rings(self, positions: np.ndarray) -> None:
        """The rings of the straight ways from ``positions`` to the goals at rest."""
        sc = self.context.scenario
        self.zones_ready = True
        rings = find_rings(self.rule, positions, self.rest_goals, float(self.required.max()),
                           self.min_radius, sc)
        followable = np.append(rings.radii >= self.min_radius, False)  # index -1: none
        self.zone_of[:] = np.where(followable[rings.zone_of], rings.zone_of, -1)
        self.centres, self.radii = rings.centres, rings.radii

    def _ring_references(self, view: SampleView) -> np.ndarray | None:
        """References around the rings of the own robots that have one now (``None``: none)."""
        r = self.rule
        own = self.context.own
        if not self.zones_ready:  # the zones hold until the next search: their test too
            self._find_rings(view.positions)
            self._own_zones = self.zone_of[own]
            self._ringed = bool(np.any(self._own_zones >= 0))
        if not self._ringed:
            return None
        zones = self._own_zones
        p, goals = view.positions, self.rest_goals
        out = None
        for k in np.flatnonzero(zones >= 0):
            i, z = own[k], zones[k]
            c, radius = self.centres[z], self.radii[z]
            gx, gy = goals[i]
            if np.hypot(gx - p[i, 0], gy - p[i, 1]) <= r.goal_distance or segment_distance(
                    p[i, 0], p[i, 1], gx, gy, c[0], c[1]) >= radius:
                continue
            busy = ring_busy(p, goals, self.zone_of, z, i, c[0], c[1], radius,
                             r.goal_distance)
            if busy < r.ring_crowd - 1:
                continue
            if out is None:
                out = view.references.copy()
            ring_path(p[i, 0], p[i, 1], gx, gy, c[0], c[1], radius, self.step, out[k])
            self.counts["ring_samples"] += 1
        return out

    def shape_references(self, view: SampleView) -> Contribution | None:
        r = self.rule
        ring = self._ring_references(view)
        if view.positions.shape[0] <= r.min_crowd:
            return None if ring is None else Contribution(references=ring)
        if view.headings is None:  # every robot ahead counts (a cosine never exceeds 2)
            headings, cos_along = self._no_headings, 2.0
        else:
            headings, cos_along = view.headings, self._cos_along
        active = roundabout_directions(
            view.positions, headings, self.rest_goals, self.context.own,
            view.scenario_references[:, -1].copy(), self.required, r.sense,
            self._cos_cone, cos_along, r.min_crowd, r.goal_distance, self.directions)
        if not active:
            return None if ring is None else Contribution(references=ring)
        out = view.references.copy() if ring is None else ring
        for k in np.flatnonzero(self.directions.any(axis=1)):
            if ring is not None and np.any(ring[k] != view.references[k]):
                continue  # on a ring
            self.counts["roundabout_samples"] += 1
            out[k] = view.own_states[k, :2] + self.offsets[:, None] * self.directions[k]
        return Contribution(references=out)


@dataclass(frozen=True)
class Rings:
    """The rings of one snapshot (:func:`find_rings`).

    Attributes
    ----------
    zone_of
        ``(n,)`` each robot's zone, ``-1`` for none.
    centres
        ``(z, 2)`` the zones' centres.
    radii
        ``(z,)`` the rings' radii: the wanted radius, cut to the room the zone has.
    wanted
        ``(z,)`` the radius that spaces the zone's members ``ring_spacing`` apart
        (at least the smallest radius a robot can follow).
    """

    zone_of: np.ndarray
    centres: np.ndarray
    radii: np.ndarray
    wanted: np.ndarray


def ring_min_radius(rule: Roundabout, scenario: Scenario, kept: float) -> float:
    r"""The smallest ring a robot can follow: :math:`\max(2 d, v_\text{ref}/\omega_\max)`,
    ``kept`` (:math:`d`) the largest distance the rows keep, m."""
    bounds = scenario.bounds
    speed = rule.speed_fraction * float(max(abs(bounds.input_lower()[0]),
                                            abs(bounds.input_upper()[0])))
    turn = min(abs(bounds.input_lower()[1]), abs(bounds.input_upper()[1]))
    return max(2.0 * kept, speed / max(turn, 1e-9))


def find_rings(rule: Roundabout, positions: np.ndarray, goals: np.ndarray, kept: float,
               min_radius: float, scenario: Scenario) -> Rings:
    """The rings of the straight ways from ``positions (n, 2)`` to ``goals (n, 2)`` (NaN:
    none at rest): the zones of :func:`sqpmpc.kernels.rings.ring_zones`, each with the
    radius ``max(min_radius, members ring_spacing / 2 pi)`` cut to its room (its
    distance to its members' starts and goals and to the pillars, less ``kept``). A
    zone whose room is below ``min_radius`` has no ring a robot can follow (the rule
    leaves it out); none in a map with walls (the routes know them, a ring does not).
    """
    r = rule
    n = positions.shape[0]
    zone_of = np.full(n, -1, dtype=np.int64)
    centres = np.zeros((n, 2))
    travelling = np.isfinite(goals[:, 0]) & (np.hypot(*(np.nan_to_num(goals) - positions).T)
                                             > r.goal_distance)
    zones = 0
    if not scenario.polygons and np.count_nonzero(travelling) >= r.ring_crowd:
        zones = ring_zones(np.array(positions, dtype=float), goals, travelling, r.ring_window,
                           math.cos(r.along), r.ring_cluster, r.ring_crowd, 0.5, zone_of,
                           centres)
    radii, wanted = np.zeros(zones), np.zeros(zones)
    for z in range(zones):
        members = np.flatnonzero(zone_of == z)
        c = centres[z]
        wanted[z] = max(min_radius, members.size * r.ring_spacing / (2.0 * np.pi))
        room = min(np.hypot(*(positions[members] - c).T).min(),
                   np.hypot(*(goals[members] - c).T).min()) - kept
        for o in scenario.obstacles:  # a pillar in the ring: no ring
            room = min(room, float(np.hypot(*(np.asarray(o.position) - c)))
                       - 0.5 * o.diameter - kept)
        radii[z] = min(wanted[z], room)
    return Rings(zone_of, centres[:zones].copy(), radii, wanted)


def crowd_without_room(scenario: Scenario, rule: Roundabout | None = None) -> bool:
    """Whether, at the start, a crowd of robots meets where its ring cannot space them.

    The roundabout passes a crowd whose straight ways cross together by sending its
    members around a ring ``ring_spacing`` apart; a ring cut by the room around it
    (its members' own starts and goals, pillars) to a radius a robot can still follow
    but below that spacing packs the crowd closer than the rule's own spacing, and the
    rules then have no motion that passes it (a 256-robot antipodal swap: a ring of
    19.3 m for the 28.5 m its robots need, 209/256 home). ``rule``: the roundabout's
    parameters (its defaults when ``None``); the rows' distance is the scenario's
    required distance.
    """
    rule = rule or Roundabout()
    if scenario.polygons or not all(isinstance(r.reference, PointReference)
                                    for r in scenario.robots):
        return False
    kept = float(scenario.required_distances().max(initial=0.0))
    min_radius = ring_min_radius(rule, scenario, kept)
    rings = find_rings(rule, scenario.initial_states()[:, :2],
                       scenario.reference_positions(0.0), kept, min_radius, scenario)
    return bool(np.any((rings.radii >= min_radius) & (rings.radii < rings.wanted)))


@dataclass(frozen=True)
class Roundabout(Rule):
    """Pass a crowd of at least ``min_crowd`` robots ahead counter-clockwise, on its right.

    See the module docstring for the rule; ``sense`` (m) is how far ahead a
    robot looks, ``cone`` (rad) the half-angle of "ahead", ``goal_distance``
    (m) the distance to the goal below which the rule is idle, ``along`` (rad)
    the angle within which a robot heading the way this one goes is traffic
    rather than a conflict (it does not count in the crowd), and
    ``speed_fraction`` the share of the largest speed the roundabout
    references move at. ``ring_crowd`` (robots), ``ring_spacing`` (m per
    robot along a ring), ``ring_window`` and ``ring_cluster`` (m) shape the
    fixed rings where straight ways cross (module docstring).
    """

    name = "roundabout"
    summary = ("a crowd of 4+ robots ahead, or a ring where 4+ straight ways cross, is passed "
               "counter-clockwise")
    instance = _RoundaboutInstance
    min_crowd: int = 4
    sense: float = 3.0
    cone: float = float(np.deg2rad(60.0))
    along: float = float(np.deg2rad(45.0))
    goal_distance: float = 1.0
    speed_fraction: float = 1.0
    ring_crowd: int = 4
    ring_spacing: float = 0.7
    ring_window: float = 1.5
    ring_cluster: float = 0.5

    def __post_init__(self) -> None:
        check_positive(self, "min_crowd", "sense", "cone", "along", "goal_distance",
                       "speed_fraction", "ring_crowd", "ring_spacing", "ring_window",
                       "ring_cluster")
        for name in ("min_crowd", "ring_crowd"):
            if not isinstance(getattr(self, name), numbers.Integral):
                raise ProblemError(f"rule 'roundabout': {name} must be an integer, "
                                   f"got {getattr(self, name)!r}")
        if self.cone >= np.pi / 2:
            raise ProblemError(f"rule 'roundabout': cone must be below pi/2, got {self.cone}")
        if self.along >= np.pi:
            raise ProblemError(f"rule 'roundabout': along must be below pi, got {self.along}")
        if self.speed_fraction > 1.0:
            raise ProblemError(f"rule 'roundabout': speed_fraction must be at most 1, "
                               f"got {self.speed_fraction}")


