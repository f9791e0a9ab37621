r"""One neighbour selection for a decentralized robot, shared by the controller and the services.

A robot with neighbour slots (:attr:`sqpmpc.control.settings.SolverSettings.neighbour_slots`)
gives its collision rows to the ``slots`` nearest neighbours within the
*interaction radius*

.. math::

    r_{il} = d_{il} + m + 2 v_\text{max} N T_s,

with :math:`d_{il}` the required distance and :math:`m` the margin of the pair
rows (``collision_margin + model_margin``, :mod:`sqpmpc.problem.plant`): a
neighbour farther than that cannot come within its distance over the horizon.
The same :class:`NeighbourSelector` answers the three questions of a sample:

- :meth:`NeighbourSelector.select`: the controller's slots (and the neighbours
  within reach left without one, for the first-input check);
- :meth:`NeighbourSelector.slotted_ids`: the ids whose plans the step reads
  (the services wait for and decode exactly those);
- :meth:`NeighbourSelector.recipients`: the robots the sender addresses its plan
  to, those that may give it a slot at the next sample (:func:`recipients`),
  with every robot's radius built as its own controller builds it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sqpmpc.kernels.collision import nearest_within
from sqpmpc.problem.scenario import Scenario

__all__ = ["NeighbourSelection", "NeighbourSelector", "NeighbourSlots", "recipients"]


@dataclass(frozen=True)
class NeighbourSelection:
    """The neighbours of one sample.

    Attributes
    ----------
    slotted
        Positions in :attr:`NeighbourSelector.others` of the neighbours given a
        slot, nearest first (slot ``e`` holds ``slotted[e]``).
    unslotted
        Positions in :attr:`NeighbourSelector.others` of the neighbours within
        the interaction radius left without a slot.
    """

    slotted: np.ndarray
    unslotted: np.ndarray


@dataclass
class NeighbourSlots:
    """What the slots of a decentralized robot's QP hold at the current sample.

    Attributes
    ----------
    index
        ``(slots,)`` scenario index of the neighbour in each slot (free slots:
        the robot's own index; their rows are off).
    neighbours
        ``(slot, id)`` of the occupied slots, nearest first.
    kinds
        ``(slots,)`` row kind of each slot (:mod:`sqpmpc.ocp.collision_rows`:
        shared, obstacle, missing, off).
    age_margins
        ``(slots,)`` extra distance for a neighbour whose plans are late, m.
    predictions, own_predictions
        ``(slots, N, 3)`` stages 1..N of each neighbour, and of this robot
        from the plan of the pair's common sample (shared rows).
    """

    index: np.ndarray
    neighbours: list[tuple[int, int]]
    kinds: np.ndarray
    age_margins: np.ndarray
    predictions: np.ndarray
    own_predictions: np.ndarray

    @classmethod
    def empty(cls, others: np.ndarray, other_ids: np.ndarray, slots: int,
              horizon: int) -> NeighbourSlots:
        """Slots filled with the first ``slots`` others (the fixed assignment without
        selection)."""
        return cls(others[:slots].copy(), list(enumerate(other_ids[:slots].tolist())),
                   np.zeros(slots, dtype=np.int8), np.zeros(slots),
                   np.zeros((slots, horizon, 3)), np.zeros((slots, horizon, 3)))


class NeighbourSelector:
    """The neighbour selection of the robot at scenario index ``index``.

    Parameters
    ----------
    scenario
        The problem (required distances, horizon, sample time).
    index
        Scenario index of the selecting robot.
    slots
        Neighbour slots of its QP (at most the number of others).
    pair_margin
        Margin of the pair rows, m (``collision_margin + model_margin``).
    max_speed
        Largest ``|v|`` the bounds allow, m/s.

    Attributes
    ----------
    others, other_ids
        Scenario indices and ids of the other robots (scenario order).
    radii
        ``(n, n)`` interaction radii of every pair (every robot's controller
        builds its row of it alike: the settings of a run are common).
    interaction_radius
        ``(n - 1,)`` this robot's radii to ``others``.
    step
        ``2 v_max Ts``: the most a distance changes between two samples, m.
    """

    def __init__(self, scenario: Scenario, index: int, slots: int, pair_margin: float,
                 max_speed: float) -> None:
        n = scenario.n_robots
        self.index = int(index)
        self.slots = int(slots)
        self.others = np.array([i for i in range(n) if i != self.index], dtype=np.int64)
        self.other_ids = scenario.ids[self.others]
        reach = 2.0 * max_speed * scenario.horizon * scenario.sample_time
        self.radii = scenario.required_distances() + pair_margin + reach
        self.interaction_radius = np.ascontiguousarray(self.radii[self.index, self.others])
        self.step = 2.0 * max_speed * scenario.sample_time
        self._chosen = np.zeros(self.slots, dtype=np.int64)  # scratch of the kernel
        self._rest = np.zeros(self.others.size, dtype=np.int64)

    def select(self, states: np.ndarray) -> NeighbourSelection:
        """The nearest neighbours within the interaction radius at ``states (n, 3)``.

        The arrays returned are views of scratch arrays, valid until the next call.
        """
        positions = np.ascontiguousarray(states[:, :2])
        used, extra = nearest_within(positions[self.index], positions, self.others,
                                     self.interaction_radius, self._chosen, self._rest)
        return NeighbourSelection(self._chosen[:used], self._rest[:extra])

    def slotted_ids(self, states: np.ndarray) -> list[int]:
        """Ids of the neighbours given a slot at ``states (n, 3)``, nearest first."""
        return [int(i) for i in self.other_ids[self.select(states).slotted]]

    def recipients(self, states: np.ndarray) -> np.ndarray:
        """Scenario indices of the robots that may give this robot a slot at the next
        sample, from the states ``(n, 3)`` of this one (:func:`recipients`)."""
        return recipients(states, self.index, self.radii, self.slots, self.step)


def recipients(states: np.ndarray, index: int, radius: np.ndarray, slots: int,
               step: float) -> np.ndarray:
    """Indices of the robots that may give robot ``index`` a slot at the next sample.

    Robot ``i`` selects at sample ``k + 1`` the ``slots`` nearest neighbours
    within ``radius[i, l]``. Between two samples a distance changes by at most
    ``step`` (both robots move at most ``v_max Ts``). So from the states
    ``(n, 3)`` of sample ``k`` alone, robot ``index`` (the sender ``j``) is
    certainly *not* in ``i``'s slots at ``k + 1`` when it cannot be within
    reach (``d_ij - step > radius[i, j]``), or when at least ``slots`` others
    ``l`` are certainly within reach (``d_il + step <= radius[i, l]``) and
    certainly nearer (``d_il + step < d_ij - step``). Every other robot is a
    recipient. The bounds are widened by a relative ``1e-9`` against rounding.

    Parameters
    ----------
    states
        Everyone's states at sample ``k`` (scenario order).
    index
        The sender's index.
    radius
        ``(n, n)`` interaction radii ``d_il + margin + 2 v_max N Ts``
        (:attr:`NeighbourSelector.radii`).
    slots
        Slots per robot (at least the number of others: no limit).
    step
        ``2 v_max Ts``, m.
    """
    n = states.shape[0]
    p = states[:, :2]
    dist = np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1])
    tol = 1e-9
    lo, hi = step * (1.0 + tol) + 1e-12, radius[index] * (1.0 + tol) + 1e-12
    d = dist[index]
    may = d - lo <= hi
    may[index] = False
    cand = np.flatnonzero(may)
    if slots >= n - 1 or cand.size == 0:
        return cand
    rows = dist[cand]  # (m, n): candidate receiver i to every l
    sure = (rows + lo <= radius[cand] * (1.0 - tol)) & (rows + lo < (d[cand] - lo)[:, None])
    sure[np.arange(cand.size), cand] = False
    sure[:, index] = False
    return cand[sure.sum(axis=1) < slots]
