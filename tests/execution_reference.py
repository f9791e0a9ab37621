"""The numpy form of :meth:`sqpmpc.coordination.schedule.Execution.advance` and
:meth:`~sqpmpc.coordination.schedule.Execution.clear_all` as they were before their
kernels (:mod:`sqpmpc.kernels.execution`): the reference the compiled execution is
compared to (tests/test_execution_kernel.py). Functions of an execution, its state read
(and its progress advanced) as the methods did."""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from sqpmpc.coordination.schedule import Execution

__all__ = ["advance", "clear_all", "yield_way"]


def _paths(execution: Execution) -> np.ndarray:
    """``(n, L, 2)`` the positions of every robot's path vertices."""
    return execution.roadmap.positions[execution.schedule.paths]


def _dependencies(execution: Execution) -> tuple[int, np.ndarray, np.ndarray]:
    """The dependencies sorted by owner, then vertex: the key base, each one's key
    ``owner * base + vertex`` and the robot it waits for (as the execution sorts them)."""
    s = execution.schedule
    order = np.lexsort((s.dep_index, s.dep_owner))
    base = int(s.lengths.max(initial=0)) + 2
    key = s.dep_owner[order].astype(np.int64) * base + s.dep_index[order]
    return base, key, s.dep_robot[order]


def advance(self: Execution, positions: np.ndarray) -> np.ndarray:
    """The numpy :meth:`sqpmpc.coordination.schedule.Execution.advance`."""
    now = np.asarray(positions, dtype=float)[self.robots]
    n, width = _paths(self).shape[:2]
    ahead = self.progress[:, None] + np.arange(0, self.window + 1)[None, :]
    valid = ahead <= (self.schedule.lengths - 1)[:, None]
    ahead = np.minimum(ahead, width - 1)
    pts = _paths(self)[np.arange(n)[:, None], ahead]  # (n, W + 1, 2)
    valid &= ahead <= self.permitted_all()[:, None]  # never past what it may enter
    gap = np.where(valid, np.hypot(*(pts - now[:, None, :]).transpose(2, 0, 1)), np.inf)
    # the later of equally near vertices: argmin over the reversed window
    best = gap.shape[1] - 1 - np.argmin(gap[:, ::-1], axis=1)
    np.maximum(self.progress, ahead[np.arange(n), best], out=self.progress)
    return self.progress

def clear_all(self: Execution, positions: np.ndarray) -> np.ndarray:
    """The numpy :meth:`sqpmpc.coordination.schedule.Execution.clear_all`."""
    out = self.permitted_all()
    now = np.asarray(positions, dtype=float)
    rows = np.flatnonzero(out > self.progress)
    if rows.size == 0 or now.shape[0] < 2:
        return out
    nxt = _paths(self)[rows, self.progress[rows] + 1]  # (q, 2)
    # the nearest robot to each next vertex, and the one after it (one is the robot
    # itself when it is the nearest): O(q log N), not all the pairs
    dist, who = cKDTree(now).query(nxt, k=2)
    gap = np.where(who[:, 0] == self.robots[rows], dist[:, 1], dist[:, 0])
    held = rows[gap < 0.5 * self.roadmap.spacing]
    out[held] = self.progress[held]
    free = np.setdiff1d(rows, held)
    if free.size >= 2:
        wait = free[yield_way(self, now, free)]
        out[wait] = self.progress[wait]
    return out

def yield_way(self: Execution, now: np.ndarray, free: np.ndarray) -> np.ndarray:
    """The numpy :meth:`sqpmpc.coordination.schedule.Execution.yield_way`: a mask over
    ``free``."""
    sep = self.roadmap.spacing - 2.0 * self.roadmap.reach
    q = free.size
    a = now[self.robots[free]]  # (q, 2) where they are
    nxt = _paths(self)[free, self.progress[free] + 1]
    d = nxt - a  # their ways
    # only a robot pushed off its path (farther than the reach from the edge it is on)
    # stands in a way the plan did not give it; one on its path is where the plan's
    # order has it
    v0 = _paths(self)[free, self.progress[free]]
    edge = nxt - v0
    length = np.maximum(np.einsum("ij,ij->i", edge, edge), 1e-12)
    g = np.clip(np.einsum("ij,ij->i", a - v0, edge) / length, 0.0, 1.0)
    off = np.hypot(*(a - v0 - g[:, None] * edge).T) > self.roadmap.reach
    if not off.any():
        return np.zeros(q, dtype=bool)
    # a robot j on r's way is within |d_r| + sep of r: only such pairs are looked at
    reach = float(np.sqrt(np.einsum("ij,ij->i", d, d).max())) + sep
    pairs = cKDTree(a).query_pairs(reach, output_type="ndarray")
    if pairs.size == 0:
        return np.zeros(q, dtype=bool)
    r, j = np.concatenate((pairs, pairs[:, ::-1])).T  # both orders: is j on r's way?
    keep = off[j]
    r, j = r[keep], j[keep]
    dr = d[r]
    dd = np.maximum(np.einsum("ij,ij->i", dr, dr), 1e-12)
    rel = a[j] - a[r]
    f = np.clip(np.einsum("ij,ij->i", rel, dr) / dd, 0.0, 1.0)
    near = rel - f[:, None] * dr
    inway = np.hypot(near[:, 0], near[:, 1]) < sep  # j on r's way
    r, j = r[inway], j[inway]
    if r.size == 0:
        return np.zeros(q, dtype=bool)
    index = np.full(self.schedule.size, -1)
    index[free] = np.arange(q)
    # the robots each one follows onto its next vertex: its dependencies on that
    # vertex, one run of the dependencies sorted by (owner, vertex)
    key_base, dep_key, dep_robot = _dependencies(self)
    want = free * key_base + self.progress[free] + 1
    lo = np.searchsorted(dep_key, want, "left")
    count = np.searchsorted(dep_key, want, "right") - lo
    rows = np.repeat(np.arange(q), count)
    deps = np.arange(rows.size) - np.repeat(np.cumsum(count) - count, count) \
        + np.repeat(lo, count)
    followed = index[dep_robot[deps]]
    key = r * q + j
    follows = rows[followed >= 0] * q + followed[followed >= 0]
    stay = ~np.isin(key, follows)
    r, j, key = r[stay], j[stay], key[stay]
    waits = ~np.isin(j * q + r, key)  # j on r's way, r not on j's
    r, j = r[waits], j[waits]
    graph = csr_matrix((np.ones(r.size), (r, j)), shape=(q, q))
    _, label = connected_components(graph, directed=True, connection="strong")
    cyclic = np.bincount(label)[label] > 1
    waiting = np.zeros(q, dtype=bool)
    waiting[r] = True
    return waiting & ~cyclic

