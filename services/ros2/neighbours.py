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

__all__ = ["CHECK_STEPS", "FAR", "KEPT_PLANS", "Neighbours"]

FAR = 1.0e4
"""Where a neighbour never heard from is put (m): beyond every interaction radius."""
KEPT_PLANS = 4
"""Plans kept per neighbour (the newest few: one stamped before each of the own instants)."""
CHECK_STEPS = 100
"""Points per sample at which :meth:`Neighbours.path_is_safe` measures the distances."""


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

    Attributes
    ----------
    plans
        Per neighbour id, its newest plans (oldest first).
    departed
        Per neighbour that left (its token disappeared): where it stopped.
    received, refused
        Plans kept, plans dropped as from the future or too old.
    blocked_by_concurrent
        The last failed check failed on a neighbour deciding at about the same instants.
    """

    def __init__(self, ids: list[int], robot_id: int, required: np.ndarray,
                 sample_time: float, horizon: int, max_speed: float, lead: float,
                 guard: float, margin: float, keep_current: bool = False) -> None:
        self.ids = [int(i) for i in ids]
        self.robot_id = int(robot_id)
        self.required = np.asarray(required, dtype=float)
        self.Ts, self.N, self.v_max = float(sample_time), int(horizon), float(max_speed)
        self.lead, self.guard, self.margin = float(lead), float(guard), float(margin)
        self.plans: dict[int, list[TimedPlan]] = {i: [] for i in self.ids if i != robot_id}
        self.departed: dict[int, Estimate] = {}
        self.received = self.refused = 0
        self.blocked_by_concurrent = False
        self.keep_current = bool(keep_current)
        """Inside the margin (never below the required distance), accept a path that gets
        no closer than the robot is now (under acceleration limits the margin holds the
        braking distance, which a robot told to stop uses up)."""

    def add(self, msg: PlanMsg, now: float) -> None:
        """Keep a neighbour's plan (validated by the node) unless from the future or too old."""
        kept = self.plans.get(msg.id)
        if kept is None:
            return
        if msg.stamp > now + self.Ts or msg.stamp < now - self.N * self.Ts:
            self.refused += 1
            return
        if any(p.stamp == msg.stamp for p in kept):
            return
        kept.append(TimedPlan(msg.stamp, msg.states, msg.inputs))
        kept.sort(key=lambda p: p.stamp)
        del kept[:-KEPT_PLANS]
        self.departed.pop(msg.id, None)  # back
        self.received += 1

    def left(self, robot_id: int, now: float) -> None:
        """Neighbour ``robot_id`` stopped (zero on shutdown): it stands where its plan had
        it, give or take a sample's reach."""
        kept = self.plans.get(robot_id)
        if not kept:
            return
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
            if left is not None:
                gap = np.hypot(path[:, 0] - left.state[0], path[:, 1] - left.state[1]) \
                    - left.uncertainty
            elif self.plans[rid]:
                kept = self.plans[rid]
                later = kept[-1].stamp + self.Ts - self.lead > now + self.guard
                concurrent = not later
                at, r = committed(kept, times[:1], self.Ts, self.v_max, later)
                if (math.hypot(own[0] - at[0, 0], own[1] - at[0, 1]) - r[0]
                        > self.required[j] + slack + 4.0 * self.v_max * self.Ts):
                    continue  # out of reach of this sample (both stretches are shorter)
                gap = self._stretch_gaps(kept, path, times, later)
            else:
                continue
            need = self.required[j] + slack
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
