"""The run buffer: what a closed-loop run produced, filled sample by sample by the
in-process simulation and by the services' plant alike.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sqpmpc.errors import ProblemError

__all__ = ["RunRecord"]



@dataclass
class RunRecord:
    """What a closed-loop run produced (possibly partial).

    Parameters
    ----------
    scenario
        The scenario that ran (duck-typed: ``name``, ``sample_time``,
        ``horizon``, ``steps``, ``n_robots``, ``ids``, ``weights.Q``,
        ``weights.R``, ``bounds``, ``required_distances()``, ``pairs()``,
        ``reference_positions(t)``).
    scheme
        ``"centralized"`` or ``"decentralized"`` (any label is accepted).
    t
        Sample times :math:`t_0..t_k`, shape ``(k+1,)``.
    states
        States :math:`(x, y, \\psi)` at every sample, shape ``(k+1, n, 3)``.
    inputs
        Applied inputs :math:`(v, \\omega)`, shape ``(k, n, 2)``; input ``i`` is
        held on :math:`[t_i, t_{i+1})`.
    solve_times
        Controller computation time per sample and controller, seconds,
        shape ``(k, c)`` with ``c = 1`` (centralized) or ``c = n``
        (decentralized, one column per robot in scenario order). A 1-D array
        is taken as one column. Wall time: it grows with the machine's load.
    solver_failures
        Controller steps in which a fallback input was applied.
    completed
        Whether the run reached the scenario's ``t_end``.
    extra
        Free extra metrics, merged into the metrics at top level.
    plant_inputs
        The inputs the plant really applied (the commanded ``inputs`` plus the
        ``[plant]`` input noise), ``(k, n, 2)``; ``None``: the commanded ones.
    horizons
        The predicted horizon (plan) of every robot computed at each sample,
        ``(k, n, N+1, 3)`` states :math:`(x, y, \\psi)` at :math:`t_i .. t_{i+N}`;
        NaN where a plan is unknown (a distributed plant that did not receive
        it); ``None``: not recorded.
    cpu_times
        The controllers' CPU time (thread time) per sample, shape of
        ``solve_times``, seconds; ``None``: not measured (a distributed plant
        records the controllers' wall times only).

    Raises
    ------
    ProblemError
        When the array shapes are inconsistent with each other or with the
        scenario's number of robots.
    """

    scenario: Any
    scheme: str
    t: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    solve_times: np.ndarray
    solver_failures: int = 0
    completed: bool = False
    extra: dict[str, Any] = field(default_factory=dict)
    plant_inputs: np.ndarray | None = None
    horizons: np.ndarray | None = None
    cpu_times: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = int(self.scenario.n_robots)
        self.t = np.asarray(self.t, dtype=float).reshape(-1)
        k = self.t.shape[0] - 1
        if k < 0:
            raise ProblemError("a run record needs at least the initial sample t_0")
        self.states = np.asarray(self.states, dtype=float)
        if self.states.shape != (k + 1, n, 3):
            raise ProblemError(
                f"states must have shape {(k + 1, n, 3)}, got {self.states.shape}")
        self.inputs = np.asarray(self.inputs, dtype=float)
        if self.inputs.size == 0 and k == 0:
            self.inputs = self.inputs.reshape(0, n, 2)
        if self.inputs.shape != (k, n, 2):
            raise ProblemError(f"inputs must have shape {(k, n, 2)}, got {self.inputs.shape}")
        st = np.asarray(self.solve_times, dtype=float)
        if st.ndim == 1:
            st = st.reshape(-1, 1)
        if st.ndim != 2 or st.shape[0] != k or st.shape[1] not in (1, n):
            raise ProblemError(
                f"solve_times must have shape ({k}, 1) or ({k}, {n}), got {st.shape}")
        self.solve_times = st
        if self.cpu_times is not None:
            cpu = np.asarray(self.cpu_times, dtype=float).reshape(st.shape[0], -1)
            if cpu.shape != st.shape:
                raise ProblemError(f"cpu_times must have the shape of solve_times {st.shape}, "
                                   f"got {np.shape(self.cpu_times)}")
            self.cpu_times = cpu
        if self.plant_inputs is not None:
            self.plant_inputs = np.asarray(self.plant_inputs, dtype=float)
            if self.plant_inputs.shape != self.inputs.shape:
                raise ProblemError(f"plant_inputs must have shape {self.inputs.shape}, got "
                                   f"{self.plant_inputs.shape}")
        if self.horizons is not None:
            self.horizons = np.asarray(self.horizons, dtype=float)
            shape = (k, n, int(self.scenario.horizon) + 1, 3)
            if self.horizons.shape != shape:
                raise ProblemError(f"horizons must have shape {shape}, got "
                                   f"{self.horizons.shape}")

    @property
    def plant_model(self) -> str:
        """The plant model of the scenario (``"euler"`` without a ``[plant]`` section)."""
        plant = getattr(self.scenario, "plant", None)
        return str(getattr(plant, "model", "euler"))

    @property
    def k(self) -> int:
        """Number of simulated samples (inputs applied), ``len(t) - 1``."""
        return int(self.t.shape[0] - 1)

    @property
    def ids(self) -> np.ndarray:
        """Robot ids as an integer array of shape ``(n,)``."""
        ids = self.scenario.ids
        if callable(ids):
            ids = ids()
        return np.asarray(ids, dtype=np.int64).reshape(-1)

    @property
    def positions(self) -> np.ndarray:
        """Positions :math:`(x, y)`, shape ``(k+1, n, 2)``."""
        return self.states[..., :2]

    def references(self) -> np.ndarray:
        """Reference positions :math:`r_j(t_i)`, shape ``(k+1, n, 2)``."""
        ref = np.asarray(self.scenario.reference_positions(self.t), dtype=float)
        return ref.reshape(self.t.shape[0], self.states.shape[1], 2)
