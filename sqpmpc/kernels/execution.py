r"""Compiled kernel of a schedule's execution (:class:`sqpmpc.coordination.schedule.Execution`).

A robot may head for its path vertex :math:`k` only when every dependency on it is
met: :math:`\text{permitted}_i = \min(L_i - 1, \min\{k_e - 1 : e \text{ unmet}\})`
over the dependencies :math:`e` owned by robot :math:`i` (vertex :math:`k_e`, waiting
for robot :math:`r_e` to reach progress :math:`m_e`), unmet while
:math:`k_e > p_i` and :math:`p_{r_e} < m_e`. Progress never decreases, so a
dependency once passed (:math:`k_e \le p_i`) or met (:math:`p_{r_e} \ge m_e`) stays
so: sorted by owner and vertex, each owner's first unmet dependency gives its
minimum, and a pointer per owner moves past the others once, not at every sample
(a 256-robot swap's plan has tens of thousands of dependencies).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["permitted", "warm_up_execution"]

_jit = numba.njit(cache=True, nogil=True)


@_jit
def permitted(progress: np.ndarray, last: np.ndarray, owners: np.ndarray, ends: np.ndarray,
              index: np.ndarray, robot: np.ndarray, need: np.ndarray, pointer: np.ndarray,
              out: np.ndarray) -> None:
    """The last path index each robot may head for, into ``out (n,)``.

    Parameters
    ----------
    progress, last
        ``(n,)`` every robot's progress and last path index.
    owners, ends
        ``(g,)`` the owner of each group of dependencies and the end of its group (the
        dependencies sorted by owner, then vertex; a group starts where the previous
        ends).
    index, robot, need
        ``(D,)`` the sorted dependencies: vertex, the robot waited for, its progress
        needed.
    pointer
        ``(g,)`` each group's first dependency not yet passed or met (updated here;
        reset to the groups' starts when a progress went down).
    out
        ``(n,)`` output.
    """
    out[:] = last
    for g in range(owners.size):
        o = owners[g]
        p = pointer[g]
        while p < ends[g] and (index[p] <= progress[o] or progress[robot[p]] >= need[p]):
            p += 1
        pointer[g] = p
        if p < ends[g] and index[p] - 1 < out[o]:
            out[o] = index[p] - 1


def warm_up_execution() -> None:
    """Compile or load the kernel with the array layouts the execution passes."""
    one = np.ones(2, dtype=np.int64)
    permitted(np.zeros(2, dtype=np.int64), one, np.zeros(1, dtype=np.int64), one[:1],
              one[:1], one[:1], one[:1], np.zeros(1, dtype=np.int64), np.empty(2, np.int64))
