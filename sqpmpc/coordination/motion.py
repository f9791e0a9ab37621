r"""The motion a robot tracks along its open roadmap path: smooth, timed, within reach.

A roadmap path is a polyline of vertices :math:`h` apart with corners (90 degrees
on a grid, half-turns where a plan steps back). A unicycle cannot follow a
corner at speed, and a reference that runs around it at :math:`v_{\max}` pulls
the robot across the corner into the wall, where its heading points into the
wall and its position-only tracking cost gives it no reason to turn (at
:math:`v = 0` the linearized unicycle's position does not depend on its
heading). :func:`path_motion` gives the motion a unicycle can make instead, and
the controller tracks it: its positions are the references of stages
:math:`1..N` and its velocities the references of the inputs, so a robot that
must turn in place is asked to (:meth:`sqpmpc.ocp.iteration.Iteration.update_motion`).

**Geometry: within the reach.** Every corner of deflection :math:`\varphi` is
replaced by the circular arc tangent to both segments whose middle is
:math:`\rho` (the roadmap's reach, :mod:`sqpmpc.coordination.roadmap`) from the
corner vertex,

.. math:: R = \frac{\rho}{\sec(\varphi/2) - 1},

(the arc's tangent points, :math:`R\tan(\varphi/2)` from the vertex, are kept to
half of each segment), so the path stays within :math:`\rho` of the roadmap's
vertices and edges, the tube in which the roadmap's separation argument holds. A
half-turn (:math:`R \to 0`) is a turn in place. The motion starts at the robot's
own pose, so that its first stage is a move the robot can make: from the robot's
projection on this path (on the segments into and out of its progress vertex,
the furthest of equally near points, so a path that steps back is followed in its
order) it heads straight for the point :math:`\max(2\rho, e)` further along the path
(:math:`e` its distance to the path; not past a turn in place or the path's end),
which closes a sideways offset within the tube over :math:`2\rho` (a heading change
of at most :math:`\arctan\frac12`) and one from outside it (a robot pushed out of
the tube) at 45 degrees at most, and joins the path there; its own heading's error
:math:`e_0` to that line is turned away along the first
:math:`|e_0| v_0 / \omega_{\max}` metres, within the line: the tightest turn at its
present speed :math:`v_0`, in place at rest. (Going back at right angles, the robot
would have to turn by 90 degrees and back within a few centimetres: a moving robot's
turn then ran past the line and its headings turned away from the path while its
positions slid onto it, a motion a unicycle cannot make.) Backwards (``reverse``) the
motion is the one of the robot turned by a half-turn, its speeds negated (the plug-in
backs up to a vertex behind a robot that may drive backwards).

**Timing: within the bounds.** Along the path the speed is the largest that
keeps :math:`|v| \le v_{\max}`, :math:`|\omega| \le \omega_{\max}` (so
:math:`v \le \omega_{\max} R` on an arc, and every heading change takes at least
:math:`|\Delta\psi| / \omega_{\max}`), :math:`|a| \le a_{\max}` from the robot's
present speed, and stops at the path's end (the last vertex it may enter now, or
its goal): the classical time-optimal profile of a path, a forward and a
backward pass over the arc length,

.. math:: v(s)^2 = \min\bigl(c(s)^2,\ \min_{s' \le s} c(s')^2 + 2 a_{\max}(s - s'),
          \ \min_{s' \ge s} c(s')^2 + 2 a_{\max}(s' - s)\bigr),

with :math:`c` the caps. Sampled at the stage times, it is a motion of the
unicycle's bounds; no parameter of it is free (:math:`\rho` comes from the
roadmap, the others are the scenario's bounds).

Safety does not depend on it: it is where the robot heads, the collision rows and
the verified first input are the controller's own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sqpmpc.kernels import motion as kernel

__all__ = ["Motion", "path_motion", "smooth_path"]


@dataclass(frozen=True)
class Motion:
    """A timed motion along a path, at the stage times ``0, T, ..., N T``.

    Attributes
    ----------
    poses
        ``(N+1, 3)`` ``(x, y, psi)``; stage 0 is the robot's own pose.
    velocities
        ``(N+1, 2)`` ``(v, omega)`` at the stages (stage 0: the robot's own).
    """

    poses: np.ndarray
    velocities: np.ndarray


def _points(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``points`` as ``(K, 2)`` contiguous floats and the headings of its steps (numpy's
    ``arctan2``: :func:`sqpmpc.kernels.motion.smooth_path`)."""
    pts = np.ascontiguousarray(points, dtype=float).reshape(-1, 2)
    steps = kernel.kept_steps(pts)
    return pts, np.arctan2(steps[:, 1], steps[:, 0])


def smooth_path(points: np.ndarray, reach: float, step: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""The polyline ``points (K, 2)`` with its corners rounded within ``reach``.

    Returns samples ``(S, 2)`` of the path, their headings ``(S,)`` (continuous,
    starting at the first segment's direction) and, for every point, the index of the
    last sample of its corner ``(K,)``; lines are sampled at most ``step`` apart, arcs
    every :data:`~sqpmpc.kernels.motion.ARC_STEP`; a turn in place is two samples at the
    vertex. A point equal to the one before it is a corner of none (its mark is the one
    before's). Compiled: :func:`sqpmpc.kernels.motion.smooth_path`.
    """
    pts, headings = _points(points)
    return kernel.smooth_path(pts, headings, float(reach), float(step))


def path_motion(points: np.ndarray, pose: np.ndarray, speed: float, reach: float,
                sample_time: float, horizon: int, max_speed: float, max_turn_rate: float,
                acceleration: float | None, stop: bool = True, within: int | None = None,
                reverse: bool = False, turn_rate: float | None = None,
                out: tuple[np.ndarray, np.ndarray] | None = None) -> Motion:
    r"""The motion along ``points (K, 2)`` (``K >= 2``: the path from the vertex behind
    the robot to the end of its open part) of a robot at ``pose (3,)`` moving at
    ``speed`` (module docstring; compiled: :func:`sqpmpc.kernels.motion.path_motion_into`).

    Parameters
    ----------
    points
        The path's vertices; the robot is projected on its first segments.
    pose
        ``(x, y, psi)`` of the robot (``psi`` continuous: the motion's headings are on its
        branch).
    speed
        The robot's forward speed, m/s (negative counts as standing).
    reach
        :math:`\rho`, m.
    sample_time, horizon
        :math:`T_s`, :math:`N`.
    max_speed, max_turn_rate
        :math:`v_{\max} > 0`, :math:`\omega_{\max} > 0`.
    acceleration
        :math:`a_{\max}` (``None``: the speed may change at once).
    stop
        Whether the robot stops at the path's end (else the path goes on beyond it).
    within
        The robot is projected on the path up to ``points[within]`` (default: the whole
        path), the furthest of equally near points: a path that comes back over itself
        (a plan's step back) is followed in its order.
    reverse
        Drive backwards (``speed`` is then the forward speed, negative when reversing):
        the motion of the robot turned by a half-turn, its speeds negated.
    turn_rate
        The robot's present turn rate, rad/s, for a model with velocity states: with
        ``speed`` it is then the motion's velocity at stage 0 (its velocities start where
        the robot's are, so the accelerations of its first sample are the ones it needs);
        ``None`` (a model whose inputs are the velocities): stage 0's velocity is the
        motion's own over its first sample.
    out
        ``(N+1, 3)`` and ``(N+1, 2)`` arrays to write the poses and velocities into (the
        motion's arrays are then these); new arrays by default.
    """
    pts, headings = _points(points)
    N = int(horizon)
    poses, velocities = (np.empty((N + 1, 3)), np.empty((N + 1, 2))) if out is None else out
    kernel.path_motion_into(
        pts, headings, float(pose[0]), float(pose[1]), float(pose[2]), float(speed),
        float(reach), float(sample_time), float(max_speed), float(max_turn_rate),
        acceleration is not None, math.nan if acceleration is None else float(acceleration),
        bool(stop), -1 if within is None else int(within), bool(reverse),
        turn_rate is not None, math.nan if turn_rate is None else float(turn_rate),
        poses, velocities)
    return Motion(poses, velocities)
