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
later one, so the graph of *waiting for* is acyclic: among the robots not at the
end of their paths, the one whose next vertex comes first in the plan waits for
nobody. It is free to move, and the robot it moves to has left its vertex (is
within :math:`\rho` of the next one), so the two keep the collision rows'
distance (:mod:`sqpmpc.coordination.roadmap`): heading for its next vertex is a
motion the NMPC can make. A robot held up (slow, pushed, braked by the safety
layer) only delays the robots that wait for it; progress resumes when it does.

**Between robots that keep the order, distinct vertices.** Two robots' progress
vertices are never the same vertex: the later one may head there only after the
earlier one reached its next vertex; so the configuration of progress vertices is
always a valid start for a new plan (:meth:`Execution.configuration`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sqpmpc.coordination.roadmap import Roadmap

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
    dep_robot, dep_index, dep_need
        Per robot ``i`` (lists of arrays): ``i`` may head for its path vertex
        ``dep_index[i][e]`` only when robot ``dep_robot[i][e]``'s progress is at least
        ``dep_need[i][e]``; sorted by ``dep_index``.
    """

    paths: np.ndarray
    entries: np.ndarray
    lengths: np.ndarray
    dep_robot: tuple[np.ndarray, ...]
    dep_index: tuple[np.ndarray, ...]
    dep_need: tuple[np.ndarray, ...]

    @classmethod
    def from_plan(cls, configs: np.ndarray) -> Schedule:
        """The schedule of a plan ``(T + 1, n)`` (vertex of every robot at every step)."""
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
        # visits of every vertex: (vertex, entry step, robot, index), in plan order
        robot = np.repeat(np.arange(n), lengths)
        index = np.concatenate([np.arange(k) for k in lengths]) if n else np.zeros(0, int)
        vertex = np.concatenate(paths) if n else np.zeros(0, int)
        enter = np.concatenate(entries) if n else np.zeros(0, int)
        order = np.lexsort((enter, vertex))
        v, r, k = vertex[order], robot[order], index[order]
        same = np.flatnonzero(v[1:] == v[:-1])  # visit same+1 follows visit same
        deps: list[list[tuple[int, int, int]]] = [[] for _ in range(n)]
        for a in same:
            later, earlier = int(r[a + 1]), int(r[a])
            if later == earlier:  # the same robot back on a vertex it left: no wait
                continue
            deps[later].append((int(k[a + 1]), earlier, int(k[a]) + 1))
        dep_robot, dep_index, dep_need = [], [], []
        for i in range(n):
            rows = sorted(deps[i])
            dep_index.append(np.array([e[0] for e in rows], dtype=np.int64))
            dep_robot.append(np.array([e[1] for e in rows], dtype=np.int64))
            dep_need.append(np.array([e[2] for e in rows], dtype=np.int64))
        return cls(padded, entry, lengths, tuple(dep_robot), tuple(dep_index),
                   tuple(dep_need))

    @property
    def size(self) -> int:
        """Number of robots."""
        return int(self.lengths.size)


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
        owner = np.repeat(np.arange(schedule.size), [d.size for d in schedule.dep_index])
        self._dep = (owner, *(np.concatenate(x) if x else np.zeros(0, np.int64) for x in (
            schedule.dep_index, schedule.dep_robot, schedule.dep_need)))

    def advance(self, positions: np.ndarray) -> np.ndarray:
        """Count progress from the measured ``positions (N, 2)`` of all robots (scenario
        order): a robot is at the path vertex nearest to it among its progress vertex
        and the next ``window`` ones (ties: the later one); progress never decreases.
        Returns the progress ``(n,)`` (read it, do not write it)."""
        now = np.asarray(positions, dtype=float)[self.robots]
        n, width = self._points.shape[:2]
        ahead = self.progress[:, None] + np.arange(0, self.window + 1)[None, :]
        valid = ahead <= self._last[:, None]
        ahead = np.minimum(ahead, width - 1)
        pts = self._points[np.arange(n)[:, None], ahead]  # (n, W + 1, 2)
        valid &= ahead <= self.permitted_all()[:, None]  # never past what it may enter
        gap = np.where(valid, np.hypot(*(pts - now[:, None, :]).transpose(2, 0, 1)), np.inf)
        # the later of equally near vertices: argmin over the reversed window
        best = gap.shape[1] - 1 - np.argmin(gap[:, ::-1], axis=1)
        np.maximum(self.progress, ahead[np.arange(n), best], out=self.progress)
        return self.progress

    def permitted_all(self) -> np.ndarray:
        """``(n,)`` the last path index every robot may head for now."""
        owner, index, robot, need = self._dep
        out = self._last.copy()
        unmet = (index > self.progress[owner]) & (self.progress[robot] < need)
        np.minimum.at(out, owner[unmet], index[unmet] - 1)
        return out

    def permitted(self, robot: int) -> int:
        """The last path index robot ``robot`` (schedule order) may head for now."""
        s = self.schedule
        p = int(self.progress[robot])
        idx = s.dep_index[robot]
        if idx.size:
            later = idx > p
            unmet = later & (self.progress[s.dep_robot[robot]] < s.dep_need[robot])
            if unmet.any():
                return int(idx[unmet].min()) - 1
        return int(self._last[robot])

    def path_points(self, robot: int, first: int, last: int) -> np.ndarray:
        """``(last - first + 1, 2)`` the positions of robot ``robot``'s path vertices
        ``first..last``."""
        return self._points[robot, first:last + 1]

    def finished(self, robot: int) -> bool:
        """Whether robot ``robot`` has reached the end of its path."""
        return bool(self.progress[robot] >= self._last[robot])

    def configuration(self) -> np.ndarray:
        """``(n,)`` every robot's progress vertex (distinct: module docstring)."""
        n = self.schedule.size
        return self.schedule.paths[np.arange(n), self.progress]
