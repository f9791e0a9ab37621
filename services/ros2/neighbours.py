"""What a ROS 2 robot knows of its neighbours: their time-stamped plans, and the check.

A robot of the ROS 2 mode applies each plan's first input from the plan's
stamp for one sample, so that arc is exact (:func:`services.ros2.timing.committed`).
:class:`Neighbours` keeps the newest plans of each neighbour and gives

- the controller its view (:meth:`Neighbours.for_controller`): every
  neighbour a moving obstacle on its exact arcs, then standing where they end;
- the check of an input (:meth:`Neighbours.path_is_safe`): along the exact arc
  of the whole sample, every required distance plus the margin from all of a
  neighbour's arc since the start of its current sample (a robot may stop at
  any moment: odometry lost, shut down); after that arc, from where it ends
  for a neighbour that decides after this check (it then has this robot's new
  plan and avoids it, or an older one and keeps out of all this robot may
  reach), from the disc it may reach since for any other one; from where a
  neighbour that left stopped, plus a sample's reach.

Plans are claims, checked (:meth:`Neighbours.add`): a plan is kept only if its
stamp is later than the neighbour's previous plan (by at least
:data:`MIN_SPACING` samples) and not more than a sample (plus the guard) ahead
of this robot's clock, if it is the only moving plan of its sample, if every
stage is reachable under the velocity bounds (inputs within them, no stage
further than ``v_max Ts`` from the one before) and if it starts where the
neighbour's own past plans put it: within the tolerance of its committed motion
at some moment of the sample before its stamp (a robot may stop at any moment),
and if it does not put the neighbour inside this robot: within its required
distance less the tolerance of where this robot's own plans had it at the plan's
stamp (two robots cannot stand in one place, and the true plans of a pair keep
the distance at every instant, :meth:`path_is_safe`). A plan that contradicts
the newest plans of a chain but follows the same chain without its plans of the
last samples (its newest plan at most :data:`FORK_BASE` samples before; any plan
within its reach for a moving plan) is kept as a fork: of two claims that cannot
both be true, the neighbour may be on either, and the check keeps out of both. A
neighbour whose plan breaks one of these is *untrusted* and named in the log;
its refused plans are never kept nor used, and nothing is added for them: where
it may be is what its kept claims and physics say (exact arcs, then its reach
since). So a process holding a robot's key can make it stand only within
:data:`FORK_BASE` samples' reach of where its plans put it (a sample's reach
beyond its last sample, ``v_max Ts`` plus the tolerance), and in the attacks
measured (``docs/ros2.md``) could not put it where it is not nor hide where it
is. Its true plans are all kept: each follows the one before it, on the chain
that holds that one (with the reach of any gap between them), or, when plans
forged since were appended to that chain, that chain without them; a true plan
is refused only if it stands and the two before it were both lost and a forged
plan that follows the chain came in between, or its robot did not do as its
plans said (the chain's reach places it again within a sample), or if
:data:`MAX_FORKS` forks newer than its own crowd it out (not proved safe).

A neighbour that left (its token disappeared) stands within a sample's reach of
where its last plan put it (a base stops on its command timeout, 0.5 s at most
without commands). A robot already inside that disc may still leave it: along
a path on which its distance to every point of the disc never decreases.

A robot that stands still, or stops at any moment, is therefore safe: whoever
decides later avoids it, whoever decided earlier kept out of all of its arc
and of where it stops or of all it could reach. At every instant, the robot of
a pair that decided last kept the distance from what the other may be doing.
"""

from __future__ import annotations

import math
import time

import numpy as np

from sqpmpc.control.plans import PlanMessage

from ..messages import PlanMsg
from .timing import Estimate, TimedPlan, arcs, committed, neighbour_estimate

__all__ = ["BOUND_SLACK", "CHECK_STEPS", "FAR", "FORK_BASE", "FORK_SAMPLES", "KEPT_PLANS",
           "MAX_FORKS", "MIN_SPACING", "OWN_PLANS", "PLAN_TOLERANCE", "Neighbours"]

FAR = 1.0e4
"""Where a neighbour never heard from is put (m): beyond every interaction radius."""
KEPT_PLANS = 16
"""Plans kept per neighbour and fork (the newest: at least three samples' worth, as
:data:`MIN_SPACING` allows at most five a sample)."""
MIN_SPACING = 0.2
"""A plan must come at least this many samples after the one before it on its chain (a
robot sends one moving plan a sample, and a standing one at most every 0.2 Ts)."""
CHECK_STEPS = 100
"""Points per sample at which :meth:`Neighbours.path_is_safe` measures the distances."""
PLAN_TOLERANCE = 0.05
"""How far a plan's stage 0 may be from where its robot's past plans put it, m (besides
the check's margin): odometry and command latency."""
BOUND_SLACK = 0.01
"""An input may exceed its bounds by this fraction of their range (the QP's tolerance)."""
FORK_BASE = 2.0
"""A standing plan forks from a chain without its plans of the last samples only: the
newest plan it keeps is stamped at most this many samples (plus the guard) before it (one
lost plan between them; from an older one, a forged claim could stand anywhere within the
reach of all that time, metres from the robot, and was kept: the freeze and herd runs). A
moving plan may fork from any plan kept, within its reach since: a robot whose plans did
not hold (its base drove on while its odometry was stale, a machine stall) moves on from
where it truly is, and a standing one is placed again by its chain's reach within a
sample."""
OWN_PLANS = 8
"""This robot's own plans kept (the newest), to refute claims that put a neighbour inside
it."""
FORK_SAMPLES = 3
"""A fork (a chain of plans contradicting another) without a plan for this many samples
is forgotten."""
MAX_FORKS = 4
"""Forks kept per neighbour (the newest)."""
CONTINUITY_STEPS = 25
"""Points of the sample before a plan's stamp at which its start is compared."""


class Neighbours:
    """The neighbours of robot ``robot_id``.

    Parameters
    ----------
    ids
        Every robot of the scenario (scenario order).
    robot_id
        This robot.
    required
        ``(n,)`` required centre distance from this robot to each robot, m.
    sample_time, horizon, max_speed
        ``Ts``, ``N``, ``v_max``.
    lead
        When robots compute a sample: this long before its instant (the fleet's).
    guard
        Bound on the clock offset between robots, s.
    margin
        Added to every required distance in the check, m.
    keep_current
        Inside the margin, accept a path that gets no closer than the robot is now.
    input_bounds
        ``(lower, upper)`` of ``(v, omega)``: a plan's inputs must lie within them
        (default: ``|v| <= max_speed`` only).
    tolerance
        How far a plan may start from where the neighbour's past plans put it, m
        (added to ``margin``).

    Attributes
    ----------
    plans
        Per neighbour id, its newest plans (oldest first).
    departed
        Per neighbour that left (its token disappeared): where it stopped.
    received, refused
        Plans kept, plans dropped as too old.
    untrusted
        Per neighbour whose plans broke the checks: how many it sent (refused).
    reasons
        Per untrusted neighbour: the first reason one of its plans was refused.
    blocked_by_concurrent
        The last failed check failed on a neighbour deciding at about the same instants.
    """

    def __init__(self, ids: list[int], robot_id: int, required: np.ndarray,
                 sample_time: float, horizon: int, max_speed: float, lead: float,
                 guard: float, margin: float, keep_current: bool = False,
                 input_bounds: tuple[np.ndarray, np.ndarray] | None = None,
                 tolerance: float = PLAN_TOLERANCE) -> None:
        self.ids = [int(i) for i in ids]
        self.robot_id = int(robot_id)
        self.required = np.asarray(required, dtype=float)
        self.Ts, self.N, self.v_max = float(sample_time), int(horizon), float(max_speed)
        self.lead, self.guard, self.margin = float(lead), float(guard), float(margin)
        self.plans: dict[int, list[TimedPlan]] = {i: [] for i in self.ids if i != robot_id}
        self.departed: dict[int, Estimate] = {}
        self.received = self.refused = 0
        self.untrusted: dict[int, int] = {}
        self.reasons: dict[int, str] = {}
        self.own: list[TimedPlan] = []
        self.forks: dict[int, list[list[TimedPlan]]] = {}
        self.tolerance = float(tolerance)
        if input_bounds is None:
            input_bounds = (np.array([-self.v_max, -np.inf]), np.array([self.v_max, np.inf]))
        self.input_lower = np.asarray(input_bounds[0], dtype=float)
        self.input_upper = np.asarray(input_bounds[1], dtype=float)
        self.blocked_by_concurrent = False
        self.keep_current = bool(keep_current)
        """Inside the margin (never below the required distance), accept a path that gets
        no closer than the robot is now (under acceleration limits the margin holds the
        braking distance, which a robot told to stop uses up)."""

    def sent(self, stamp: float, states: np.ndarray, inputs: np.ndarray) -> None:
        """This robot's own plan, as sent (stamp ``stamp``): where it is then, to refute a
        neighbour's claim to stand inside it (:meth:`add`)."""
        self.own = [*self.own[-(OWN_PLANS - 1):],
                    TimedPlan(float(stamp), np.asarray(states, dtype=float),
                              np.asarray(inputs, dtype=float))]

    def add(self, msg: PlanMsg, now: float) -> str | None:
        """Keep a neighbour's plan (validated by the node) if it passes the checks of the
        module notes; returns why it is a false claim or contradicts another (its robot
        is then untrusted), ``None`` when kept, too old or a repeat.

        A plan that continues the neighbour's kept plans (its chain) is appended to it.
        One that does not, but continues a fork (a chain that branched off, below) or
        a chain (the kept one or a fork) without its newest plans, those of the last
        :data:`FORK_BASE` samples, is kept as a fork: two claims that cannot both be
        true, so the neighbour may be on either, and the check keeps out of both
        (:meth:`path_is_safe`). One that continues nothing is refused, not kept.
        A plan with the stamp of a kept one is a repeat when it is the same plan or a
        stop where that one starts (the check keeps out of all of that one's arc, a stop
        anywhere on it included); any other is a second claim of that instant.
        """
        kept = self.plans.get(msg.id)
        if kept is None:
            return None
        if msg.stamp < now - self.N * self.Ts:
            self.refused += 1  # late, not false
            return None
        forks = self.forks.setdefault(msg.id, [])
        if any(p.stamp == msg.stamp and self._covers(p, msg)
               for c in (kept, *forks) for p in c):
            return None  # a repeat, or a stop announced at the same instant where it was
        plan = TimedPlan(msg.stamp, msg.states, msg.inputs)
        why = self._implausible(msg, now)
        if why is None:
            why = self._discontinuous(kept, msg)
            if why is None:
                kept.append(plan)
                del kept[:-KEPT_PLANS]
                self.departed.pop(msg.id, None)  # back
                self.received += 1
                self._prune(msg.id, now)
                return None
            fork = next((c for c in forks if self._discontinuous(c, msg) is None), None)
            if fork is None:
                base, chain = self._base(msg, [kept, *forks])
                if base is not None:
                    fork = list(base)
                    forks.append(fork)
                    why = f"contradicting its plan stamped {chain[len(base)].stamp:.3f} ({why})"
            if fork is not None:
                fork.append(plan)
                del fork[:-KEPT_PLANS]
                self.received += 1
                self._prune(msg.id, now)
        self.untrusted[msg.id] = self.untrusted.get(msg.id, 0) + 1
        self.reasons.setdefault(msg.id, why)
        return why

    def _covers(self, kept: TimedPlan, msg: PlanMsg) -> bool:
        """Whether ``msg``, stamped as ``kept``, adds nothing to it: the same plan, or a stop
        where ``kept`` starts."""
        x, u = np.asarray(msg.states, dtype=float), np.asarray(msg.inputs, dtype=float)
        if x.shape == kept.states.shape and u.shape == kept.inputs.shape \
                and np.array_equal(x, kept.states) and np.array_equal(u, kept.inputs):
            return True
        return not u.any() and float(np.hypot(*(x[:, :2] - kept.states[0, :2]).T).max()) \
            <= self.tolerance

    def _base(self, msg: PlanMsg, chains: list[list[TimedPlan]]
              ) -> tuple[list[TimedPlan] | None, list[TimedPlan]]:
        """The longest chain ``msg`` follows that is one of ``chains`` without its newest
        plans, keeping one stamped at most :data:`FORK_BASE` samples (plus the guard)
        before ``msg`` if ``msg`` stands (any, within its reach, if it moves); and the chain
        it is part of."""
        moving = bool(np.asarray(msg.inputs, dtype=float)[0].any())
        oldest = -math.inf if moving else msg.stamp - FORK_BASE * self.Ts - self.guard
        for chain in chains:
            for i in range(len(chain) - 1, 0, -1):
                if chain[i - 1].stamp < oldest:
                    break
                if self._discontinuous(chain[:i], msg) is None:
                    return chain[:i], chain
        return None, chains[0]

    def _prune(self, robot_id: int, now: float) -> None:
        """Forget forks without a plan for :data:`FORK_SAMPLES` samples (at most
        :data:`MAX_FORKS`, the newest); a chain that went silent that long while a fork
        goes on is replaced by the fork (the neighbour is there)."""
        kept, forks = self.plans[robot_id], self.forks[robot_id]
        life = FORK_SAMPLES * self.Ts
        live = [c for c in forks if c[-1].stamp >= now - life]
        if live and kept and kept[-1].stamp < now - life:
            newest = max(live, key=lambda c: c[-1].stamp)
            live.remove(newest)
            kept[:] = newest
        live.sort(key=lambda c: c[-1].stamp)
        self.forks[robot_id] = live[-MAX_FORKS:]

    def _implausible(self, msg: PlanMsg, now: float) -> str | None:
        """Why ``msg`` is no plan of a robot at all, if so (its stamp, bounds, stages)."""
        if msg.stamp > now + self.Ts + self.guard:
            return f"stamped {msg.stamp - now:.3f} s ahead of this robot's clock"
        u, x = np.asarray(msg.inputs, dtype=float), np.asarray(msg.states, dtype=float)
        slack = BOUND_SLACK * np.where(np.isfinite(self.input_upper - self.input_lower),
                                       self.input_upper - self.input_lower, 0.0)
        if (u < self.input_lower - slack).any() or (u > self.input_upper + slack).any():
            return "an input outside the velocity bounds"  # beyond the QP's tolerance
        step = float(np.hypot(*np.diff(x[:, :2], axis=0).T).max(initial=0.0))
        if step > self.v_max * self.Ts + self.tolerance:
            return f"a stage {step:.3f} m from the one before (beyond v_max Ts)"
        own = self.own
        if own and msg.stamp >= own[0].stamp:
            at, r = committed(own, np.array([msg.stamp]), self.Ts, self.v_max, False)
            gap = float(np.hypot(x[0, 0] - at[0, 0], x[0, 1] - at[0, 1]))
            need = float(self.required[self.ids.index(msg.id)]) - self.tolerance
            if r[0] == 0.0 and gap < need:  # where this robot is exactly, at that instant
                return f"standing {gap:.3f} m from this robot (inside it)"
        return None

    def _discontinuous(self, kept: list[TimedPlan], msg: PlanMsg) -> str | None:
        """Why ``msg`` cannot follow the plans ``kept`` (a chain), if so."""
        if not kept:
            return None
        last = kept[-1]
        u, x = np.asarray(msg.inputs, dtype=float), np.asarray(msg.states, dtype=float)
        if msg.stamp < last.stamp:
            return f"stamped {last.stamp - msg.stamp:.3f} s before its previous plan"
        if msg.stamp - last.stamp < MIN_SPACING * self.Ts - 1e-6:
            return (f"stamped {msg.stamp - last.stamp:.3f} s after its previous plan (at most "
                    f"one every {MIN_SPACING:g} Ts)")
        if u[0].any():  # a moving plan: one per sample (stops may be announced any time)
            moving = [p.stamp for p in kept if p.inputs[0].any()]
            if moving and msg.stamp - moving[-1] < self.Ts - self.guard:
                return (f"a second moving plan {msg.stamp - moving[-1]:.3f} s after the "
                        "last (one per sample)")
        times = msg.stamp - self.Ts * np.linspace(0.0, 1.0, CONTINUITY_STEPS + 1)
        pos, rad = committed(kept, times, self.Ts, self.v_max, False)
        off = float((np.hypot(pos[:, 0] - x[0, 0], pos[:, 1] - x[0, 1]) - rad).min())
        if off > self.margin + self.tolerance:
            return f"starts {off:.3f} m from where its past plans put it"
        return None

    def left(self, robot_id: int, now: float) -> None:
        """Neighbour ``robot_id`` stopped (zero on shutdown): it stands where its plan had
        it, give or take a sample's reach."""
        kept = self.plans.get(robot_id)
        if not kept:
            return
        self.forks.pop(robot_id, None)
        est = neighbour_estimate(kept, now, self.Ts, self.v_max)
        if est is not None:
            self.departed[robot_id] = Estimate(est.state, est.uncertainty + self.v_max * self.Ts)
        kept.clear()

    def for_controller(self, t: float, sample: int
                       ) -> tuple[np.ndarray, dict[int, PlanMessage]]:
        """Every robot's state at wall time ``t`` (own row left zero; robots never heard
        from far away) and, per neighbour heard from, its motion at the own stage times
        ``t + i Ts`` as a plan of ``sample - 1`` (which the controller shifts to stages
        1..N): exact arcs, then standing where the last one ends."""
        N = self.N
        states = np.zeros((len(self.ids), 3))
        plans: dict[int, PlanMessage] = {}
        times = t + self.Ts * np.arange(-1, N)
        for j, rid in enumerate(self.ids):
            if rid == self.robot_id:
                continue
            left = self.departed.get(rid)
            if left is not None:
                states[j] = left.state
                pos = np.repeat(left.state[None, :2], N + 1, axis=0)
            elif self.plans[rid]:
                pos, _ = committed(self.plans[rid], times, self.Ts, self.v_max, True)
                states[j, :2] = pos[1]
                states[j, 2] = self._heading(self.plans[rid], t)
            else:
                states[j] = (FAR + 10.0 * j, FAR, 0.0)
                continue
            stage = np.zeros((N + 1, 3))
            stage[:, :2] = pos
            plans[rid] = PlanMessage(rid, sample - 1, stage, np.zeros((N, 2)))
        return states, plans

    def awaited(self, own: np.ndarray, t: float, now: float) -> bool:
        """Whether a neighbour that may come near ``own`` during the sample at wall time ``t``
        has decided its own sample before this robot (its next instant in ``[t - Ts, t)``,
        its decision ``lead`` before that, no later than ``now`` plus the guard) and its plan
        is not here yet: waiting for it (it is in flight) spares the check the disc it may
        reach. Only a neighbour deciding earlier is awaited, so two never wait for each
        other."""
        reach = 4.0 * self.v_max * self.Ts + self.margin
        for j, rid in enumerate(self.ids):
            if rid == self.robot_id or rid in self.departed or not self.plans.get(rid):
                continue
            kept = self.plans[rid]
            nxt = kept[-1].stamp + self.Ts
            if not (t - self.Ts <= nxt < t and nxt - self.lead <= now + self.guard):
                continue
            at, r = committed(kept, np.array([t]), self.Ts, self.v_max, False)
            if math.hypot(own[0] - at[0, 0], own[1] - at[0, 1]) - r[0] \
                    <= self.required[j] + reach:
                return True
        return False

    def _heading(self, kept: list[TimedPlan], t: float) -> float:
        """A neighbour's heading at wall time ``t`` on the arc of its newest plan stamped at or
        before ``t`` (held at the arc's end; the rules read it, e.g. ``roundabout``'s
        "heading the way this robot goes is traffic")."""
        best = kept[0]
        for plan in kept:
            if plan.stamp <= t:
                best = plan
        tau = min(max(t - best.stamp, 0.0), self.Ts)
        u = best.inputs[0]
        return float(best.states[0, 2] + float(u[1]) * tau)

    def path_is_safe(self, own: np.ndarray, u: np.ndarray, t: float) -> bool:
        """Whether applying ``u`` from ``own`` at wall time ``t`` for one sample keeps every
        neighbour's distance plus the margin at every instant (module notes).

        A neighbour may stop at any moment (its odometry lost, shut down): at each
        instant it is anywhere on its arc from the start of the sample it is in up to
        that instant, so the distance is measured to all of that stretch.
        """
        dt = self.Ts / CHECK_STEPS
        times = t + dt * np.arange(CHECK_STEPS + 1)
        path = arcs(own, float(u[0]), float(u[1]), times - t)
        now = time.time()
        slack = self.margin + self.v_max * dt  # between check points both move v_max dt/2
        for j, rid in enumerate(self.ids):
            if rid == self.robot_id:
                continue
            left = self.departed.get(rid)
            concurrent = False
            need = self.required[j] + slack
            if left is not None:
                gap = np.hypot(path[:, 0] - left.state[0], path[:, 1] - left.state[1]) \
                    - left.uncertainty
                if float(gap.min()) < need and _leaves(path, left.state[:2],
                                                       left.uncertainty):
                    continue  # inside its disc already, and getting no closer to any of it
            elif self.plans[rid]:
                kept = self.plans[rid]
                later = kept[-1].stamp + self.Ts - self.lead > now + self.guard
                concurrent = not later
                chains = [(kept, later), *((f, False) for f in self.forks.get(rid, ()))]
                near = []  # the claims within reach of this sample (it may be on any)
                for chain, hold in chains:
                    at, r = committed(chain, times[:1], self.Ts, self.v_max, hold)
                    if (math.hypot(own[0] - at[0, 0], own[1] - at[0, 1]) - r[0]
                            <= self.required[j] + slack + 4.0 * self.v_max * self.Ts):
                        near.append((chain, hold))  # (both stretches are shorter)
                if not near:
                    continue
                gap = np.min([self._stretch_gaps(c, path, times, h) for c, h in near],
                             axis=0)
            else:
                continue
            if self.keep_current:
                need = max(float(self.required[j]), min(need, float(gap[0])))
            if float(gap.min()) < need:
                self.blocked_by_concurrent = concurrent
                return False
        return True

    def _stretch_gaps(self, kept: list[TimedPlan], path: np.ndarray, times: np.ndarray,
                      later: bool) -> np.ndarray:
        """Per check time, the distance from ``path`` to everywhere the neighbour may be: its
        positions from the start of its current sample up to then (minus their radii)."""
        dt = float(times[1] - times[0])
        stamps = np.array([p.stamp for p in kept])
        start = stamps[np.clip(np.searchsorted(stamps, times, side="right") - 1, 0, None)]
        back = int(min(np.ceil(max(0.0, times[0] - float(start.min())) / dt), 2 * CHECK_STEPS))
        grid = np.concatenate((times[0] - dt * np.arange(back, 0, -1), times))
        pos, rad = committed(kept, grid, self.Ts, self.v_max, later)
        dist = np.hypot(path[:, None, 0] - pos[None, :, 0],
                        path[:, None, 1] - pos[None, :, 1]) - rad[None, :]
        first = np.clip(np.floor((start - grid[0]) / dt + 1e-9), 0, None).astype(np.int64)
        last = back + np.arange(times.size)
        cols = np.arange(grid.size)
        dist[(cols[None, :] < first[:, None]) | (cols[None, :] > last[:, None])] = np.inf
        return dist.min(axis=1)


def _leaves(path: np.ndarray, centre: np.ndarray, radius: float) -> bool:
    """Whether moving along ``path`` ``(T, 2)`` never brings it closer to any point of the
    disc (``centre``, ``radius``): outside the disc, every step ``d`` from a point ``p``
    has ``d . (p - centre) >= |d| radius`` (``min`` over the disc's points ``q`` of
    ``d . (p - q)``)."""
    w = path[:-1] - centre[None, :]
    d = np.diff(path, axis=0)
    if (np.hypot(w[:, 0], w[:, 1]) <= radius).any():
        return False
    return bool(((d * w).sum(axis=1) >= np.hypot(d[:, 0], d[:, 1]) * radius - 1e-12).all())
