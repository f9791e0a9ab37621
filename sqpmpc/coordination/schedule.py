r"""Delay-tolerant execution of a roadmap plan: an action dependency graph.

A plan (:func:`sqpmpc.coordination.mapf.plan_paths`) fixes, for every vertex,
the order in which robots pass it. Execution keeps that order and nothing else
(Hönig et al., *Persistent and Robust Execution of MAPF Schedules in
Warehouses*, RA-L 2019): each robot's path is its plan with the waits removed,
:math:`v^i_0, v^i_1, \dots, v^i_{L_i}`, and robot :math:`i` may head for
:math:`v^i_k` only when every robot :math:`j` that the plan has at
:math:`v^i_k` before :math:`i` has *reached the vertex after it* on its own path
(its progress :math:`p_j \ge k_j + 1`, :math:`k_j` its visit's index).

Progress :math:`p_j` is the index of the path vertex robot :math:`j` is
nearest to, among its progress vertex and the next few (the vertices it can pass
within the horizon), counted from the measured positions, never decreasing: a
robot is *at* :math:`v_k` once it is in the part of its way nearer to :math:`v_k`
than to the vertices around it on its path. Every
controller counts it for every robot from the same measurements, so the
decentralized controllers agree without a coordinator.

**No deadlock.** The dependencies point from an earlier step of the plan to a
later one, or to the same step where a robot follows another onto the vertex it
leaves; plans have no rotation (:mod:`sqpmpc.coordination.mapf`), so no chain of
following closes, and the graph of *waiting for* is acyclic: among the robots not at the
end of their paths, the one whose next vertex comes first in the plan waits for
nobody. It is free to move, and the robot it moves to has left its vertex (is
within :math:`\rho` of the next one), so the two keep the collision rows'
distance (:mod:`sqpmpc.coordination.roadmap`): heading for its next vertex is a
motion the NMPC can make. A robot held up (slow, pushed, braked by the safety
layer) only delays the robots that wait for it; progress resumes when it does.

**Diagonal moves** (:attr:`~sqpmpc.coordination.roadmap.Roadmap.diagonals`) *pass*
the two other corners of their square: each pass is a visit of the corner at the
step the robot enters the diagonal's end, ordered with the corner's other visits,
and the robot has left it once it has reached that end. So a robot crosses a square
only after the robots planned on its corners before it have left them, and the
robots planned there after it wait until it is across.

**Between robots that keep the order, distinct vertices.** Two robots' progress
vertices are never the same vertex: the later one may head there only after the
earlier one reached its next vertex; so the configuration of progress vertices is
always a valid start for a new plan (:meth:`Execution.configuration`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sqpmpc.coordination.roadmap import Roadmap
from sqpmpc.kernels.execution import advance, clear, permitted

__all__ = ["Execution", "Schedule"]


@dataclass(frozen=True, eq=False)
class Schedule:
    """The paths of a plan and the order of the robots at every vertex.

    Attributes
    ----------
    paths
        ``(n, L)`` each robot's path vertices (waits removed), padded with its last
        vertex; ``lengths[i]`` of them are its own.
    entries
        ``(n, L)`` the plan's step at which the robot enters each path vertex.
    lengths
        ``(n,)`` number of vertices of each path.
    dep_owner, dep_index, dep_robot, dep_need
        ``(D,)`` each, one entry per dependency: robot ``dep_owner[e]`` may head for its
        path vertex ``dep_index[e]`` only when robot ``dep_robot[e]``'s progress is at
        least ``dep_need[e]``.
    """

    paths: np.ndarray
    entries: np.ndarray
    lengths: np.ndarray
    dep_owner: np.ndarray
    dep_index: np.ndarray
    dep_robot: np.ndarray
    dep_need: np.ndarray

    @classmethod
    def from_plan(cls, configs: np.ndarray,
                  corners: dict[tuple[int, int], tuple[int, int]] | None = None) -> Schedule:
        """The schedule of a plan ``(T + 1, n)`` (vertex of every robot at every step).

        ``corners`` gives the two corners ``(b, c)`` of each diagonal move ``(a, d)``
        (:attr:`sqpmpc.coordination.roadmap.Roadmap.diagonals`): the move *passes* them,
        a visit at the step it enters ``d``, which the robot has left once it has
        reached ``d`` (not the vertex after it)."""
        configs = np.asarray(configs, dtype=np.int64)
        steps, n = configs.shape
        paths: list[np.ndarray] = []
        entries: list[np.ndarray] = []
        for i in range(n):
            column = configs[:, i]
            change = np.flatnonzero(np.concatenate(([True], column[1:] != column[:-1])))
            paths.append(column[change])
            entries.append(change)
        lengths = np.array([p.size for p in paths], dtype=np.int64)
        width = int(lengths.max(initial=1))
        padded = np.empty((n, width), dtype=np.int64)
        entry = np.empty((n, width), dtype=np.int64)
        for i in range(n):
            padded[i, :lengths[i]] = paths[i]
            padded[i, lengths[i]:] = paths[i][-1]
            entry[i, :lengths[i]] = entries[i]
            entry[i, lengths[i]:] = steps
        # visits of every vertex: (vertex, entry step, robot, index, progress that
        # leaves it), in plan order
        robot = np.repeat(np.arange(n), lengths)
        index = np.concatenate([np.arange(k) for k in lengths]) if n else np.zeros(0, int)
        vertex = np.concatenate(paths) if n else np.zeros(0, int)
        enter = np.concatenate(entries) if n else np.zeros(0, int)
        leave = index + 1
        if corners:
            passes = [(x, int(entries[i][k]), i, k) for i in range(n)
                      for k in range(1, int(lengths[i]))
                      for x in corners.get((int(paths[i][k - 1]), int(paths[i][k])), ())]
            if passes:
                extra = np.asarray(passes, dtype=np.int64)
                vertex = np.concatenate((vertex, extra[:, 0]))
                enter = np.concatenate((enter, extra[:, 1]))
                robot = np.concatenate((robot, extra[:, 2]))
                index = np.concatenate((index, extra[:, 3]))
                leave = np.concatenate((leave, extra[:, 3]))
        order = np.lexsort((enter, vertex))
        v, r, k, out = vertex[order], robot[order], index[order], leave[order]
        same = np.flatnonzero(v[1:] == v[:-1])  # visit same+1 follows visit same
        # the same robot back on a vertex it left waits for nobody
        same = same[r[same + 1] != r[same]]
        return cls(padded, entry, lengths, r[same + 1], k[same + 1], r[same], out[same])

    @property
    def size(self) -> int:
        """Number of robots."""
        return int(self.lengths.size)

    def predicted_arrivals(self, positions: np.ndarray, headings: np.ndarray, speed: float,
                           turn_rate: float) -> np.ndarray:
        r"""When each robot reaches the end of its path if the schedule is executed by
        unicycles at their bounds: ``(n,)`` seconds.

        Robot :math:`i` reaches its path vertex :math:`k + 1` at

        .. math::

            A_i(k + 1) = \max\Big(A_i(k) + \frac{|\Delta\theta_i(k)|}{\omega_{\max}},
            \max_{e \to (i, k + 1)} A_{j_e}(m_e)\Big) + \frac{\lVert v_{k+1} -
            v_k\rVert}{v_{\max}}, \qquad A_i(0) = 0,

        turning in place at :math:`v_k` from its heading (its last move's direction, at
        the start ``headings[i]``) to the next move's while it waits for the robots it
        depends on (:attr:`dep_robot` reaching :attr:`dep_need`). The waits of the plan
        are not kept: this is the execution of :class:`Execution`, which keeps the order
        at the vertices only. Speeding up and slowing down are left out, so it is a
        model for comparing plans, not a bound. The dependencies are acyclic (module
        docstring), so the longest-path fixed point below is reached in at most as many
        passes as the longest chain of dependencies.

        Parameters
        ----------
        positions
            ``(V, 2)`` the roadmap's vertex positions.
        headings
            ``(n,)`` the robots' headings at the start, rad (NaN: unknown, the first
            turn takes no time).
        speed, turn_rate
            :math:`v_{\max}` (m/s) and :math:`\omega_{\max}` (rad/s), positive.
        """
        n, width = self.paths.shape
        if n == 0:
            return np.zeros(0)
        pts = np.asarray(positions, dtype=float)[self.paths]  # (n, L, 2)
        step = np.diff(pts, axis=1)  # (n, L - 1, 2): zero past each path's end
        travel = np.hypot(step[..., 0], step[..., 1]) / float(speed)
        moving = travel > 0.0
        direction = np.arctan2(step[..., 1], step[..., 0])
        # the heading before each move: the last move's direction, else the start's
        before = np.empty_like(direction)
        if width > 1:
            before[:, 0] = np.asarray(headings, dtype=float)
            before[:, 1:] = direction[:, :-1]
        bend = np.abs((direction - before + np.pi) % (2.0 * np.pi) - np.pi)
        turning = np.where(moving & np.isfinite(bend), bend / float(turn_rate), 0.0)
        arrive = np.zeros((n, width))
        # the dependencies of each move k -> k + 1 (owner, index k + 1)
        owner, index = self.dep_owner, self.dep_index
        robot, need = self.dep_robot, self.dep_need
        flat = owner * width + index
        for _ in range(max(1, owner.size + 1)):
            ready = np.zeros(n * width)
            np.maximum.at(ready, flat, arrive[robot, need])
            ready = ready.reshape(n, width)
            new = np.zeros_like(arrive)
            for k in range(width - 1):
                depart = np.maximum(new[:, k] + turning[:, k], ready[:, k + 1])
                new[:, k + 1] = np.where(moving[:, k], depart + travel[:, k], new[:, k])
            if np.array_equal(new, arrive):
                break
            arrive = new
        return arrive[np.arange(n), self.lengths - 1]


class Execution:
    """One controller's view of a schedule's execution: every robot's progress.

    Parameters
    ----------
    schedule
        The plan's schedule (robots in the order of ``robots``).
    roadmap
        Its roadmap.
    robots
        ``(n,)`` scenario indices of the scheduled robots.
    window
        How many path vertices ahead a robot's progress may jump in one sample
        (at least the number of vertices a robot can pass in one sample, plus one).
    """

    def __init__(self, schedule: Schedule, roadmap: Roadmap, robots: np.ndarray,
                 window: int) -> None:
        self.schedule = schedule
        self.roadmap = roadmap
        self.robots = np.asarray(robots, dtype=np.int64)
        self.progress = np.zeros(schedule.size, dtype=np.int64)
        self.window = max(int(window), 1)
        self._points = roadmap.positions[schedule.paths]  # (n, L, 2)
        self._last = schedule.lengths - 1
        # the dependencies sorted by owner, then vertex (permitted_all: kernels.execution)
        order = np.lexsort((schedule.dep_index, schedule.dep_owner))
        owner = schedule.dep_owner[order]
        self._dep_index = np.ascontiguousarray(schedule.dep_index[order], dtype=np.int64)
        self._dep_robot = np.ascontiguousarray(schedule.dep_robot[order], dtype=np.int64)
        self._dep_need = np.ascontiguousarray(schedule.dep_need[order], dtype=np.int64)
        self._key_base = int(schedule.lengths.max(initial=0)) + 2  # (owner, vertex) as one
        self._dep_key = owner.astype(np.int64) * self._key_base + self._dep_index
        starts = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]]) if owner.size else \
            np.zeros(0, dtype=np.int64)
        self._owners = np.ascontiguousarray(owner[starts], dtype=np.int64)
        self._starts = starts.astype(np.int64)
        self._ends = np.append(starts[1:], owner.size).astype(np.int64)
        self._pointer = self._starts.copy()
        self._seen = self.progress.copy()  # the progress the pointers were moved for

    def advance(self, positions: np.ndarray) -> np.ndarray:
        """Count progress from the measured ``positions (N, 2)`` of all robots (scenario
        order): a robot is at the path vertex nearest to it among its progress vertex
        and the next ``window`` ones (ties: the later one), never past the last it may
        enter; progress never decreases. Compiled:
        :func:`sqpmpc.kernels.execution.advance`.
        Returns the progress ``(n,)`` (read it, do not write it)."""
        now = np.ascontiguousarray(positions, dtype=float)
        advance(self.progress, self._last, self.permitted_all(), self._points, now,
                self.robots, self.window)
        return self.progress

    def resume(self, positions: np.ndarray) -> np.ndarray:
        """Count progress from one measurement, for a controller that joins an execution
        under way (started late, or restarted mid-run) without the positions before it.

        :meth:`advance` counts from the history (a robot's way back over a vertex it
        passed, a window of vertices per sample); from a progress of zero, one
        measurement of robots far along their paths leaves it stuck behind them, and
        the controller then holds its own robot for robots that have long passed.
        Here each robot's *target* is the last visit on its path of the vertex nearest
        to it; every robot's progress moves up to its target as far as the plan's order
        allows (the order of the robots it waits for, also moved up), repeated until
        nothing moves, and ends on its last visit of that vertex within what it
        reached. On the runs of the test mazes this is the progress counted from the
        history at every sample; a robot back on a vertex it passed before can be counted
        at its later visit (ahead of the history's count) until the others' counts
        catch up, which :meth:`advance` then keeps (progress never decreases).
        Returns the progress ``(n,)`` (read it, do not write it)."""
        now = np.asarray(positions, dtype=float)[self.robots]
        n, width = self._points.shape[:2]
        index = np.arange(width)[None, :]
        valid = index <= self._last[:, None]
        gap = np.where(valid, np.hypot(*(self._points - now[:, None, :]).transpose(2, 0, 1)),
                       np.inf)
        nearest = valid & (gap <= gap.min(axis=1, keepdims=True) + 1e-9)
        target = width - 1 - np.argmax(nearest[:, ::-1], axis=1)  # last visit
        start = self.progress.copy()
        while True:  # at most one pass per robot that moves
            moved = np.maximum(self.progress, np.minimum(target, self.permitted_all()))
            if np.array_equal(moved, self.progress):
                break
            self.progress[:] = moved
        within = nearest & (index <= self.progress[:, None])
        last = np.where(within.any(axis=1), width - 1 - np.argmax(within[:, ::-1], axis=1), 0)
        self.progress[:] = np.maximum(start, last)
        return self.progress

    def permitted_all(self) -> np.ndarray:
        """``(n,)`` the last path index every robot may head for now."""
        out = np.empty_like(self._last)
        permitted(self.progress, self._last, self._owners, self._ends, self._dep_index,
                  self._dep_robot, self._dep_need, self._pointer, self._starts, self._seen,
                  out)
        return out

    def clear_all(self, positions: np.ndarray) -> np.ndarray:
        r"""``(n,)`` :meth:`permitted_all`, where a robot's next path vertex is also clear:
        a robot whose next vertex has another robot within half the spacing (the
        ``positions (N, 2)`` of all robots, scenario order) holds at its progress vertex.

        In the plan's order nobody is there: the robots before it on that vertex are
        counted past it only once nearer to their next vertex, which on the roadmap's
        edges is farther than half the spacing from it, and the robots after it wait
        for it. A robot found there was pushed off its own path by the collision rows
        (a grid formation of 64 robots: robot 42 pushed 0.58 m sideways, onto the next
        vertex of robot 27, which came on towards it; both free, each in the other's
        way to the end of the run). Heading for that vertex would pin the pushed robot
        against the way back to its path; holding at its own vertex leaves it the room.
        The hold waits only on a robot going back to its own path, which waits for no
        one to do so, so no cycle of waiting is added.

        Of the robots still free, one whose way to its next vertex another free robot
        stands on gives way to it: two robots pushed off their paths
        and pressed together at the kept distance, both free, each heading where the
        other's way goes, stood so to the end of a run (a grid formation of 64 robots,
        seed 0, on the plan without the turns' steps; re-planning from where they stood
        gave them the same ways). The one on the other's way is left to go first.

        Precisely, a free robot whose straight way from where it is to its next vertex passes
        within the kept distance :math:`s = h - 2\rho` of another free robot pushed off its
        path (farther than :math:`\rho` from the edge it is on), whose own way is clear of
        it and which is not one the plan has on that vertex before it (that one it
        follows), waits: the edge from it to that robot in the graph of waiting. Such a
        wait is taken only where it closes no cycle of waiting, so one robot of every
        chain is free. Compiled: :func:`sqpmpc.kernels.execution.clear`, which looks at
        no more than the robots asked about (:meth:`clear`) depend on."""
        return self.clear(positions, np.arange(self.schedule.size))

    def clear(self, positions: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """``(m,)`` :meth:`clear_all` for the robots ``rows (m,)`` (schedule indices) only:
        a controller asks for its own robot's. The same decisions, looking at the robots
        near its way and, for a cycle of waiting, those they wait for, not every robot's
        next vertex (a controller of a 256-robot swap would otherwise check 256 robots'
        every sample for its one)."""
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        out = np.empty(rows.size, dtype=np.int64)
        clear(np.ascontiguousarray(positions, dtype=float), self.robots, self._points,
              self.progress, self.permitted_all(), float(self.roadmap.spacing),
              float(self.roadmap.reach), self._dep_key, self._dep_robot, self._key_base,
              rows, out)
        return out

    def path_points(self, robot: int, first: int, last: int) -> np.ndarray:
        """``(last - first + 1, 2)`` the positions of robot ``robot``'s path vertices
        ``first..last``."""
        return self._points[robot, first:last + 1]

    def finished(self, robot: int) -> bool:
        """Whether robot ``robot`` has reached the end of its path."""
        return bool(self.progress[robot] >= self._last[robot])

    def all_finished(self) -> bool:
        """Whether every robot has reached the end of its path."""
        return bool(np.all(self.progress >= self._last))

    def configuration(self) -> np.ndarray:
        """``(n,)`` every robot's progress vertex (distinct: module docstring)."""
        n = self.schedule.size
        return self.schedule.paths[np.arange(n), self.progress]
