r"""Variable and constraint layout of the multiple-shooting QP, with its fixed sparsity.

A QP handles ``m`` *own* robots (all robots for the centralized scheme, one
for a decentralized controller) over a horizon ``N``. Each robot owns the
block

.. math::

    (\chi_0, u_0, \chi_1, u_1, \dots, u_{N-1}, \chi_N) \in \mathbb{R}^{5N+3},

robots are stacked, and the slack variables of the softened collision rows
(stages 2..N) come last. The constraint rows of :math:`l \le A z \le u` are, in
order: initial states, dynamics, input bounds, optional position bounds,
internal collision rows (both robots of a pair are own robots), external
collision rows (an own robot against a neighbour that is data), slack
non-negativity.

The sparsity of :math:`P` (upper triangle) and :math:`A` is decided here once.
Entries are listed in a fixed *entry order* (blocks below); :attr:`A_order`
and :attr:`P_order` map entry order to the CSC data order that OSQP uses, so
values computed per block are written with one fancy-index operation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from sqpmpc.errors import ProblemError
from sqpmpc.models.base import RobotModel
from sqpmpc.models.paper import UNICYCLE_A_PATTERN, UnicycleModel

__all__ = ["A_PATTERN", "B_PATTERN", "CURV_PATTERN", "QPLayout"]

#: The paper unicycle's structural entries of A_k and B_k (the default model's).
A_PATTERN = UNICYCLE_A_PATTERN
B_PATTERN = UnicycleModel.b_pattern
#: Upper-triangular curvature entries among the unicycle's (psi, v, omega).
CURV_PATTERN = tuple(np.triu_indices(len(UnicycleModel.curvature_offsets)))


@dataclass(frozen=True)
class QPLayout:
    """Index maps of the sparse QP.

    Parameters
    ----------
    n_robots
        Number of own robots ``m``.
    horizon
        Prediction horizon ``N``.
    internal_pairs
        ``(P, 2)`` local robot indices of pairs whose both positions are variables.
    n_external
        External collision slots per own robot ``E`` (neighbours treated as data).
    position_bounds
        Whether rows bounding (x, y) on stages 1..N exist.
    model
        The robot model (a :class:`~sqpmpc.models.base.RobotModel` or its class):
        its dimensions ``nx``, ``nu``, the Jacobians' patterns, the curvature
        variables and the velocity states, bounded on stages 1..N by their own
        rows (after the position rows). Default: the paper's unicycle.
    """

    n_robots: int
    horizon: int
    internal_pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    n_external: int = 0
    position_bounds: bool = False
    model: RobotModel | type[RobotModel] = UnicycleModel

    def __post_init__(self) -> None:
        pairs = np.asarray(self.internal_pairs, dtype=np.int64).reshape(-1, 2)
        if self.n_robots < 1 or self.horizon < 1 or self.n_external < 0:
            raise ProblemError(
                f"QPLayout needs n_robots >= 1, horizon >= 1, n_external >= 0; got "
                f"{self.n_robots}, {self.horizon}, {self.n_external}"
            )
        if pairs.size and (pairs.min() < 0 or pairs.max() >= self.n_robots):
            raise ProblemError(f"internal_pairs must index 0..{self.n_robots - 1}")
        object.__setattr__(self, "internal_pairs", pairs)
        self._build()

    # ------------------------------------------------------------------ sizes
    @property
    def block_size(self) -> int:
        """Variables per robot, ``(nx + nu) N + nx`` (``5N + 3`` for the unicycle)."""
        return (self.model.nx + self.model.nu) * self.horizon + self.model.nx

    @property
    def stage_size(self) -> int:
        """Variables per stage, ``nx + nu``."""
        return self.model.nx + self.model.nu

    @property
    def n_pairs(self) -> int:
        """Number of internal pairs ``P``."""
        return int(self.internal_pairs.shape[0])

    def _build(self) -> None:  # noqa: PLR0915 - one linear construction
        m, N, E, P = self.n_robots, self.horizon, self.n_external, self.n_pairs
        nb = self.block_size
        NX, NU = self.model.nx, self.model.nu
        a_pattern, b_pattern = self.model.a_pattern, self.model.b_pattern
        base = np.arange(m)[:, None] * nb
        stage = np.arange(N + 1)[None, :] * (NX + NU)
        state_index = base[:, :, None] + stage[:, :, None] + np.arange(NX)[None, None, :]
        input_index = (
            base[:, :, None] + stage[:, :N, None] + NX + np.arange(NU)[None, None, :]
        )
        n_slack_int = P * (N - 1)
        n_slack_ext = m * E * (N - 1)
        n_slack = n_slack_int + n_slack_ext
        n_var = m * nb + n_slack
        slack_int = (m * nb + np.arange(n_slack_int)).reshape(P, N - 1)
        slack_ext = (m * nb + n_slack_int + np.arange(n_slack_ext)).reshape(m, E, N - 1)

        rows: list[np.ndarray] = []
        cols: list[np.ndarray] = []
        row = 0

        def add(r: np.ndarray, c: np.ndarray) -> slice:
            start = sum(x.size for x in rows)
            rows.append(np.asarray(r, dtype=np.int64).ravel())
            cols.append(np.asarray(c, dtype=np.int64).ravel())
            return slice(start, start + rows[-1].size)

        # initial states
        init_rows = row + np.arange(m * NX).reshape(m, NX)
        s_init = add(init_rows, state_index[:, 0, :])
        row += m * NX
        # dynamics: chi_{i+1} - A chi_i - B u_i = c_i
        dyn_rows = row + np.arange(m * N * NX).reshape(m, N, NX)
        s_dyn_I = add(dyn_rows, state_index[:, 1:, :])
        s_dyn_A = add(
            dyn_rows[:, :, a_pattern[0]], state_index[:, :N, :][:, :, a_pattern[1]]
        )
        s_dyn_B = add(dyn_rows[:, :, b_pattern[0]], input_index[:, :, b_pattern[1]])
        row += m * N * NX
        # input bounds
        input_rows = row + np.arange(m * N * NU).reshape(m, N, NU)
        s_inp = add(input_rows, input_index)
        row += m * N * NU
        # position bounds on stages 1..N
        if self.position_bounds:
            pos_rows = row + np.arange(m * N * 2).reshape(m, N, 2)
            s_pos = add(pos_rows, state_index[:, 1:, :2])
            row += m * N * 2
        else:
            pos_rows = np.zeros((m, N, 2), dtype=np.int64)[:, :0]
            s_pos = slice(0, 0)
        # velocity-state bounds on stages 1..N (models with velocity states)
        vel = np.asarray(self.model.velocity_states, dtype=np.int64)
        vel_rows = row + np.arange(m * N * vel.size).reshape(m, N, vel.size)
        s_vel = add(vel_rows, state_index[:, 1:, :][:, :, vel]) if vel.size else slice(0, 0)
        row += m * N * vel.size
        # internal collision rows: n'(p_a - p_b) + s >= b on stages 1..N
        int_rows = row + np.arange(P * N).reshape(P, N)
        a, b = self.internal_pairs[:, 0], self.internal_pairs[:, 1]
        pos_a = state_index[a, 1:, :2]  # (P, N, 2)
        pos_b = state_index[b, 1:, :2]
        s_int = add(
            np.repeat(int_rows[:, :, None], 4, axis=2),
            np.concatenate((pos_a, pos_b), axis=2),
        )
        s_int_slack = add(int_rows[:, 1:], slack_int)
        row += P * N
        # external collision rows: n' p_j + s >= b
        ext_rows = row + np.arange(m * E * N).reshape(m, E, N)
        own_pos = np.broadcast_to(state_index[:, None, 1:, :2], (m, E, N, 2))
        s_ext = add(np.repeat(ext_rows[..., None], 2, axis=3), own_pos)
        s_ext_slack = add(ext_rows[:, :, 1:], slack_ext)
        row += m * E * N
        # slack >= 0
        slack_rows = row + np.arange(n_slack)
        s_slack = add(slack_rows, m * nb + np.arange(n_slack))
        row += n_slack
        n_con = row

        A_rows = np.concatenate(rows)
        A_cols = np.concatenate(cols)
        A_order, A_pattern = _csc_order(A_rows, A_cols, (n_con, n_var))

        # P: full diagonal plus the curvature blocks of stages 0..N-1 on the variables that
        # enter the dynamics nonlinearly (the unicycle's psi, v, omega)
        offsets = np.asarray(self.model.curvature_offsets, dtype=np.int64)
        trio = (base[:, :, None] + stage[:, :N, None] + offsets[None, None, :])
        curv = tuple(np.triu_indices(offsets.size))
        off = curv[0] != curv[1]
        P_rows = np.concatenate(
            (np.arange(n_var), trio[:, :, curv[0][off]].ravel())
        )
        P_cols = np.concatenate(
            (np.arange(n_var), trio[:, :, curv[1][off]].ravel())
        )
        P_order, P_pattern = _csc_order(P_rows, P_cols, (n_var, n_var))

        for name, value in {
            "n_var": n_var,
            "n_con": n_con,
            "n_slack": n_slack,
            "state_index": state_index,
            "input_index": input_index,
            "slack_internal_index": slack_int,
            "slack_external_index": slack_ext,
            "init_rows": init_rows,
            "dyn_rows": dyn_rows,
            "input_rows": input_rows,
            "position_rows": pos_rows,
            "velocity_rows": vel_rows,
            "internal_rows": int_rows,
            "external_rows": ext_rows,
            "slack_rows": slack_rows,
            "A_slices": {
                "init": s_init, "dyn_I": s_dyn_I, "dyn_A": s_dyn_A, "dyn_B": s_dyn_B,
                "input": s_inp, "position": s_pos, "velocity": s_vel, "internal": s_int,
                "internal_slack": s_int_slack, "external": s_ext,
                "external_slack": s_ext_slack, "slack": s_slack,
            },
            "A_nnz": A_rows.size,
            "A_rows": A_rows,
            "A_cols": A_cols,
            "A_order": A_order,
            "A_order_inverse": np.argsort(A_order),
            "A_pattern": A_pattern,
            "P_nnz": P_rows.size,
            "P_order": P_order,
            "P_order_inverse": np.argsort(P_order),
            "P_pattern": P_pattern,
            "P_diag_slice": slice(0, n_var),
            "P_curv_slice": slice(n_var, P_rows.size),
            "curvature_index": trio,
            "a_pattern": a_pattern,
            "b_pattern": b_pattern,
            "curvature_pattern": curv,
        }.items():
            object.__setattr__(self, name, value)

    # --------------------------------------------------------------- helpers
    def split_primal(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States ``(m, N+1, nx)`` and inputs ``(m, N, nu)`` of a primal vector."""
        return z[self.state_index], z[self.input_index]

    def join_primal(
        self, states: np.ndarray, inputs: np.ndarray, slacks: np.ndarray | None = None
    ) -> np.ndarray:
        """Primal vector from states ``(m, N+1, nx)``, inputs ``(m, N, nu)`` and slacks."""
        z = np.zeros(self.n_var)
        z[self.state_index] = states
        z[self.input_index] = inputs
        if slacks is not None:
            z[self.n_var - self.n_slack:] = slacks
        return z

    def A_times(self, values_in_entry_order: np.ndarray, z: np.ndarray) -> np.ndarray:
        """``A z`` for ``A`` given by its entry-order values (no matrix is built)."""
        return np.bincount(self.A_rows, values_in_entry_order * z[self.A_cols],
                           minlength=self.n_con)

    def A_transpose_times(self, values_in_entry_order: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``A^T y`` for ``A`` given by its entry-order values (no matrix is built)."""
        return np.bincount(self.A_cols, values_in_entry_order * y[self.A_rows],
                           minlength=self.n_var)

    def csc(self, values_in_entry_order: np.ndarray, which: str) -> sp.csc_matrix:
        """A CSC matrix with this layout's pattern and the given entry-order values."""
        pattern = self.A_pattern if which == "A" else self.P_pattern
        order = self.A_order if which == "A" else self.P_order
        data = np.empty(order.size)
        data[order] = values_in_entry_order
        return sp.csc_matrix((data, pattern.indices, pattern.indptr), shape=pattern.shape)


def _csc_order(
    rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]
) -> tuple[np.ndarray, sp.csc_matrix]:
    """Position in CSC data of each (row, col) entry; rejects duplicates."""
    ids = np.arange(1, rows.size + 1, dtype=float)
    coo = sp.coo_matrix((ids, (rows, cols)), shape=shape)
    if coo.tocsr().nnz != rows.size or np.unique(rows * shape[1] + cols).size != rows.size:
        raise ProblemError("internal error: duplicate entries in the QP sparsity pattern")
    csc = coo.tocsc()
    csc.sort_indices()
    order = np.empty(rows.size, dtype=np.int64)
    order[csc.data.astype(np.int64) - 1] = np.arange(rows.size)
    return order, csc
