"""Robots on their own clocks: exact unicycle arcs, time-stamped plans read at other times.

A robot of the ROS 2 mode samples at its own instants ``T_k = T_0 + k Ts``
(wall clock, Unix s); its neighbours sample at theirs. A plan sent by a
neighbour carries the wall time ``stamp`` of its stage 0 and, from that
time on, the robot applies the plan's first input for one sample, exactly.
So at any time ``T`` in ``[stamp, stamp + Ts]`` the neighbour is where the
unicycle arc from the plan's stage 0 with its first input puts it
(:func:`plan_position`); after ``stamp + Ts`` it follows plans not seen
yet, and all that is known is that it stays within ``v_max (T - stamp - Ts)``
of where this plan had it at ``stamp + Ts`` (:func:`neighbour_estimate`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sqpmpc.problem.plant import ramp_accelerations

RAMP_STEP = 0.01
"""Longest stretch :func:`own_motion` takes on one arc while the velocities ramp, s."""

__all__ = ["RAMP_STEP", "Estimate", "TimedPlan", "arc", "arcs", "committed",
           "neighbour_estimate", "own_motion", "plan_position", "ramp"]


def arc(state: np.ndarray, v: float, omega: float, dt: float) -> np.ndarray:
    """The unicycle's state ``(x, y, psi)`` after ``dt`` s at constant ``(v, omega)``
    (the exact solution, a straight line when ``omega`` is 0)."""
    x, y, psi = float(state[0]), float(state[1]), float(state[2])
    turn = omega * dt
    if abs(turn) < 1e-9:
        return np.array([x + v * dt * math.cos(psi + 0.5 * turn),
                         y + v * dt * math.sin(psi + 0.5 * turn), psi + turn])
    r = v / omega
    return np.array([x + r * (math.sin(psi + turn) - math.sin(psi)),
                     y - r * (math.cos(psi + turn) - math.cos(psi)), psi + turn])


@dataclass(frozen=True, slots=True)
class TimedPlan:
    """A neighbour's plan with the wall time of its stage 0.

    Attributes
    ----------
    stamp
        Wall time (Unix s) of stage 0.
    states
        ``(N+1, 3)`` predicted states at ``stamp + i Ts``.
    inputs
        ``(N, 2)`` predicted inputs (the first is applied from ``stamp`` for ``Ts``).
    """

    stamp: float
    states: np.ndarray
    inputs: np.ndarray


def plan_position(plan: TimedPlan, t: float, sample_time: float) -> np.ndarray:
    """The state the plan predicts at wall time ``t`` (on the arc of each stage's input;
    before ``stamp``: stage 0; past the horizon: the last input held)."""
    tau = t - plan.stamp
    if tau <= 0.0:
        return plan.states[0].copy()
    n = plan.inputs.shape[0]
    i = min(int(tau // sample_time), n - 1)
    u = plan.inputs[i]
    return arc(plan.states[i], float(u[0]), float(u[1]), tau - i * sample_time)


@dataclass(frozen=True, slots=True)
class Estimate:
    """A neighbour's state at some time and how far off it may be (m)."""

    state: np.ndarray
    uncertainty: float


def neighbour_estimate(plans: Sequence[TimedPlan], t: float, sample_time: float,
                       max_speed: float) -> Estimate | None:
    """Where a neighbour is at wall time ``t`` from the plans received (any order).

    The newest plan with ``stamp <= t`` is used: within one sample of its
    stamp the neighbour is exactly on its first arc (uncertainty 0); later,
    it is within ``max_speed (t - stamp - Ts)`` of the plan's state at
    ``stamp + Ts``. ``None`` when no plan starts at or before ``t``.
    """
    best = None
    for plan in plans:
        if plan.stamp <= t and (best is None or plan.stamp > best.stamp):
            best = plan
    if best is None:
        return None
    late = t - best.stamp - sample_time
    if late <= 0.0:
        return Estimate(plan_position(best, t, sample_time), 0.0)
    return Estimate(plan_position(best, best.stamp + sample_time, sample_time),
                    max_speed * late)


def arcs(state: np.ndarray, v: float, omega: float, dt: np.ndarray) -> np.ndarray:
    """:func:`arc` at every ``dt`` (array): positions ``(T, 2)``."""
    x, y, psi = float(state[0]), float(state[1]), float(state[2])
    turn = omega * dt
    if abs(omega) * float(np.max(dt, initial=0.0)) < 1e-9:
        return np.stack((x + v * dt * math.cos(psi), y + v * dt * math.sin(psi)), axis=-1)
    r = v / omega
    return np.stack((x + r * (np.sin(psi + turn) - math.sin(psi)),
                     y - r * (np.cos(psi + turn) - math.cos(psi))), axis=-1)


def committed(plans: Sequence[TimedPlan], times: np.ndarray, sample_time: float,
              max_speed: float, hold_after: bool) -> tuple[np.ndarray, np.ndarray]:
    """Where a neighbour is at ``times`` from its plans: positions ``(T, 2)`` and radii ``(T,)``.

    A robot applies each plan's first input from the plan's stamp for one
    sample: at ``t`` within the first sample of the newest plan stamped at or
    before ``t`` it is exactly on that arc (radius 0). Past the end of a plan's
    first sample it is within ``max_speed`` times the time since of that arc's
    end: a gap before a newer plan (one was lost), or after the newest one,
    unless ``hold_after`` (the neighbour decides its next input knowing this
    robot's new plan, so that it stands still at the arc's end counts as
    this robot's obligation, not a bound on where it is). Before the oldest
    plan: within ``max_speed`` times the time until its stamp of its stage 0.
    ``plans`` sorted by stamp, not empty.
    """
    pos = np.empty((times.size, 2))
    rad = np.zeros(times.size)
    stamps = np.array([p.stamp for p in plans])
    which = np.searchsorted(stamps, times, side="right") - 1
    for i in np.unique(which):
        sel = which == i
        t = times[sel]
        if i < 0:
            first = plans[0]
            pos[sel] = first.states[0, :2]
            rad[sel] = max_speed * (first.stamp - t)
            continue
        plan = plans[i]
        u = plan.inputs[0]
        tau = t - plan.stamp
        inside = tau <= sample_time
        pos[sel] = arcs(plan.states[0], float(u[0]), float(u[1]),
                        np.minimum(tau, sample_time))
        if not (i == len(plans) - 1 and hold_after):
            rad[sel] = np.where(inside, 0.0, max_speed * (tau - sample_time))
    return pos, rad



def ramp(v0: np.ndarray, target: np.ndarray, dt: float, within: float,
         limits: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Velocities ``(v, omega)`` ``dt`` s after a command ``target`` at velocities ``v0``,
    and their mean over those ``dt`` s.

    Under acceleration ``limits`` ``(lower, upper)`` (CONTRACT 1c) each velocity
    changes linearly at ``clip((target - v0) / within, lower, upper)`` until it
    reaches the target: with ``within`` the sample time, as the plant's robots
    (the target reached within one sample when the limits allow).
    """
    v0, target = np.asarray(v0, dtype=float), np.asarray(target, dtype=float)
    if dt <= 0.0:
        return v0.copy(), v0.copy()
    rate = ramp_accelerations(target, v0, within, limits[0], limits[1])
    moving = rate != 0.0
    reach = np.full(v0.shape, np.inf)
    reach[moving] = (target - v0)[moving] / rate[moving]  # time to the target
    tau = np.minimum(np.maximum(reach, 0.0), dt)
    end = np.where(reach <= dt, target, v0 + rate * dt)
    mean = (tau * (v0 + 0.5 * rate * tau) + (dt - tau) * end) / dt
    return end, mean


def own_motion(odometry: tuple[float, np.ndarray, float, float],
               sent: Sequence[tuple[float, float, float]], t: float, sample_time: float,
               limits: tuple[np.ndarray, np.ndarray] | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """A robot's pose ``(x, y, psi)`` and velocities ``(v, omega)`` at wall time ``t``.

    From its newest ``odometry`` ``(time, pose, v, omega)``, carried forward on
    exact arcs with the measured velocities and then with each command
    ``(time, v, omega)`` of ``sent`` (time order) given after the odometry and
    before ``t``, at once. Under acceleration ``limits`` (CONTRACT 1c) the
    velocities ramp toward each command as :func:`ramp` (a command given
    before the odometry is still reached by its time plus ``sample_time``),
    in stretches of at most :data:`RAMP_STEP` s each on the arc of its mean
    velocities.
    """
    t0, pose, v, w = odometry
    state = np.asarray(pose, dtype=float)
    vel = np.array([v, w], dtype=float)
    target, within = vel.copy(), sample_time
    for ts, cv, cw in sent:
        if ts >= t:
            break
        if ts <= t0:
            if limits is not None:
                target, within = np.array([cv, cw]), max(sample_time - (t0 - ts), 1e-9)
            continue
        state, vel = _stretch(state, vel, target, ts - t0, within, limits)
        t0, target, within = ts, np.array([cv, cw], dtype=float), sample_time
    return _stretch(state, vel, target, max(0.0, t - t0), within, limits)


def _stretch(state: np.ndarray, vel: np.ndarray, target: np.ndarray, dt: float,
             within: float, limits: tuple[np.ndarray, np.ndarray] | None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Pose and velocities ``dt`` s on (``target`` in force: at once without limits)."""
    if limits is None:
        return arc(state, float(target[0]), float(target[1]), dt), target
    pieces = max(1, math.ceil(dt / RAMP_STEP))
    for i in range(pieces):  # the rate is the command's: ``within`` shrinks as time goes
        end, mean = ramp(vel, target, dt / pieces, max(within - i * dt / pieces, 1e-9),
                         limits)
        state, vel = arc(state, float(mean[0]), float(mean[1]), dt / pieces), end
    return state, vel
