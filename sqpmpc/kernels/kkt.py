r"""Compiled kernels of the active-set QP backend: a sparse :math:`LDL^\top` of a
quasi-definite KKT matrix on a fixed pattern and the primal-dual active-set iteration.

The QP is

.. math::

    \min_z \tfrac12 z^\top P z + q^\top z \quad\text{s.t.}\quad l \le A z \le u,

with multipliers in OSQP's convention (:math:`Pz + q + A^\top y = 0`, :math:`y_i > 0` on
an active upper side, :math:`y_i < 0` on an active lower side).

**Active set.** Each row is *at its upper side*, *at its lower side* or *inactive*
(rows with :math:`l_i = u_i` are always at their value). Given a working set
:math:`W` with target values :math:`b_W`, the equality-constrained QP is one linear
system with the regularized KKT matrix of fixed pattern

.. math::

    K = \begin{pmatrix} P + \delta I & \tilde A^\top \\ \tilde A & -E \end{pmatrix},
    \qquad \tilde a_i = \begin{cases} a_i & i \in W \\ 0 & i \notin W\end{cases},\quad
    E_{ii} = \begin{cases} \varepsilon & i \in W \\ 1 & i \notin W\end{cases},

right-hand side :math:`(-q, b_W, 0)`, so an inactive row gets :math:`y_i = 0` exactly.
:math:`K` is quasi-definite (:math:`P + \delta I \succ 0`, :math:`E \succ 0`), so
an :math:`LDL^\top` factorization exists for every symmetric ordering without
pivoting; iterative refinement against the unregularized system
(:math:`\delta = \varepsilon = 0`) removes the regularization's error.
The next working set follows the semismooth-Newton (primal-dual active set) rule
with a constant :math:`c > 0`:

.. math::

    i \text{ at } u_i \iff y_i + c\,(a_i z - u_i) > 0, \qquad
    i \text{ at } l_i \iff y_i + c\,(a_i z - l_i) < 0.

A working set that the rule reproduces is a KKT point: every inactive row
satisfies :math:`l_i \le a_i z \le u_i` (as :math:`y_i = 0`), every row at a side
has a multiplier of the right sign. Warm-started from the previous sample's
solution, the working set of a real-time iteration's QP is usually right at once
(one factorization).

**Factorization.** :func:`ldl_symbolic` and :func:`ldl_factor` are QDLDL's
elimination-tree and up-looking numeric factorization (Stellato, Banjac et al.,
``osqp/qdldl``, Apache 2.0) on the upper triangle of a symmetrically permuted
matrix in CSC form: :math:`K = L D L^\top`, :math:`L` unit lower triangular.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["ACTIVE_SET_CONVERGED", "ACTIVE_SET_FACTOR_FAILED", "ACTIVE_SET_MAX_ITER",
           "active_set_solve", "ldl_factor", "ldl_solve", "ldl_symbolic", "qp_residuals",
           "warm_up_kkt"]

_jit = numba.njit(cache=True, nogil=True)

#: :func:`active_set_solve` found a working set the rule reproduces.
ACTIVE_SET_CONVERGED = 1
#: :func:`active_set_solve` stopped at its iteration cap.
ACTIVE_SET_MAX_ITER = 0
#: a zero pivot or a non-finite value.
ACTIVE_SET_FACTOR_FAILED = -1


@_jit
def ldl_symbolic(Ap: np.ndarray, Ai: np.ndarray, etree: np.ndarray, Lnz: np.ndarray,
                 work: np.ndarray) -> int:
    """Elimination tree ``etree (n,)`` and column counts ``Lnz (n,)`` of :math:`L` for the
    upper triangle ``(Ap, Ai)`` (CSC, diagonal included); returns ``nnz(L)``, or -1 if an
    entry lies below the diagonal."""
    n = Ap.shape[0] - 1
    for i in range(n):
        work[i] = 0
        Lnz[i] = 0
        etree[i] = -1
    for j in range(n):
        work[j] = j
        for p in range(Ap[j], Ap[j + 1]):
            i = Ai[p]
            if i > j:
                return -1
            while work[i] != j:
                if etree[i] == -1:
                    etree[i] = j
                Lnz[i] += 1
                work[i] = j
                i = etree[i]
    total = 0
    for i in range(n):
        total += Lnz[i]
    return total


@_jit
def ldl_factor(Ap: np.ndarray, Ai: np.ndarray, Ax: np.ndarray, Lp: np.ndarray,
               Li: np.ndarray, Lx: np.ndarray, D: np.ndarray, Dinv: np.ndarray,
               Lnz: np.ndarray, etree: np.ndarray, iwork: np.ndarray,
               fwork: np.ndarray) -> int:
    r"""Numeric :math:`LDL^\top` of the upper triangle ``(Ap, Ai, Ax)``: ``Lp (n+1,)``,
    ``Li, Lx (nnz(L),)``, ``D, Dinv (n,)``; ``Lnz, etree`` from :func:`ldl_symbolic`;
    scratch ``iwork (4n,)`` and ``fwork (n,)``. Returns the number of positive pivots, or
    -1 on a zero or non-finite pivot."""
    n = Ap.shape[0] - 1
    y_markers = iwork[:n]
    y_idx = iwork[n:2 * n]
    elim = iwork[2 * n:3 * n]
    next_space = iwork[3 * n:4 * n]
    y_vals = fwork
    Lp[0] = 0
    for i in range(n):
        Lp[i + 1] = Lp[i] + Lnz[i]
        y_markers[i] = 0
        y_vals[i] = 0.0
        D[i] = 0.0
        next_space[i] = Lp[i]
    positive = 0
    for k in range(n):
        n_y = 0
        for p in range(Ap[k], Ap[k + 1]):
            b = Ai[p]
            if b == k:
                D[k] = Ax[p]
                continue
            y_vals[b] = Ax[p]
            nxt = b
            if y_markers[nxt] == 0:
                y_markers[nxt] = 1
                elim[0] = nxt
                n_e = 1
                nxt = etree[b]
                while nxt != -1 and nxt < k:
                    if y_markers[nxt] == 1:
                        break
                    y_markers[nxt] = 1
                    elim[n_e] = nxt
                    n_e += 1
                    nxt = etree[nxt]
                while n_e > 0:
                    n_e -= 1
                    y_idx[n_y] = elim[n_e]
                    n_y += 1
        for i in range(n_y - 1, -1, -1):
            c = y_idx[i]
            end = next_space[c]
            yc = y_vals[c]
            for j in range(Lp[c], end):
                y_vals[Li[j]] -= Lx[j] * yc
            Li[end] = k
            Lx[end] = yc * Dinv[c]
            D[k] -= yc * Lx[end]
            next_space[c] = end + 1
            y_vals[c] = 0.0
            y_markers[c] = 0
        if D[k] == 0.0 or not math.isfinite(D[k]):
            return -1
        if D[k] > 0.0:
            positive += 1
        Dinv[k] = 1.0 / D[k]
    return positive


@_jit
def ldl_solve(Lp: np.ndarray, Li: np.ndarray, Lx: np.ndarray, Dinv: np.ndarray,
              x: np.ndarray) -> None:
    r"""Solve :math:`LDL^\top x = b` in place (``x`` holds ``b`` on entry)."""
    n = Dinv.shape[0]
    for i in range(n):
        xi = x[i]
        for j in range(Lp[i], Lp[i + 1]):
            x[Li[j]] -= Lx[j] * xi
    for i in range(n):
        x[i] *= Dinv[i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for j in range(Lp[i], Lp[i + 1]):
            s -= Lx[j] * x[Li[j]]
        x[i] = s


@_jit
def _working_set(Az: np.ndarray, y: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                 c: float, tau: float, side: np.ndarray, first: bool) -> bool:
    """The rule's working set into ``side (m,)`` (1 upper, -1 lower, 2 equality, 0 off),
    with a band ``tau``: a row enters a side when its test passes by more than ``tau``
    and leaves it when the test fails by more than ``tau`` (a weakly active row, at its
    bound with a zero multiplier, does not flip on round-off); the ``first`` working set
    takes every row within the band (a cold start's slacks at 0). Returns whether it
    changed."""
    changed = False
    for i in range(Az.shape[0]):
        lo, up = lower[i], upper[i]
        current = side[i]
        hi_test = y[i] + c * (Az[i] - up)
        lo_test = y[i] + c * (Az[i] - lo)
        if lo == up:
            new = 2
        elif up < math.inf and (hi_test > tau or (
                (first or current == 1) and hi_test >= -tau)):
            new = 1
        elif lo > -math.inf and (lo_test < -tau or (
                (first or current == -1) and lo_test <= tau)):
            new = -1
        else:
            new = 0
        if new != current:
            changed = True
            side[i] = new
    return changed


@_jit
def _residual(P_values: np.ndarray, P_rows: np.ndarray, P_cols: np.ndarray, q: np.ndarray,
              A_values: np.ndarray, A_rows: np.ndarray, A_cols: np.ndarray,
              lower: np.ndarray, upper: np.ndarray, side: np.ndarray, z: np.ndarray,
              y: np.ndarray, perm: np.ndarray, out: np.ndarray, Az: np.ndarray,
              scratch: np.ndarray) -> None:
    """The unregularized KKT system's residual at ``(z, y)`` for the working set ``side``,
    permuted into ``out (n+m,)``; ``Az (m,)`` and ``scratch (n+m,)`` scratch."""
    n = z.shape[0]
    m = y.shape[0]
    r = scratch
    for j in range(n):
        r[j] = -q[j]
    for e in range(P_values.shape[0]):
        i, j, v = P_rows[e], P_cols[e], P_values[e]
        r[i] -= v * z[j]
        if i != j:
            r[j] -= v * z[i]
    for i in range(m):
        Az[i] = 0.0
    for e in range(A_values.shape[0]):
        i = A_rows[e]
        if side[i] != 0:
            r[A_cols[e]] -= A_values[e] * y[i]
            Az[i] += A_values[e] * z[A_cols[e]]
    for i in range(m):
        s = side[i]
        if s == 0:
            r[n + i] = y[i]  # the row -y_i = 0
        elif s == 1:
            r[n + i] = upper[i] - Az[i]
        else:
            r[n + i] = lower[i] - Az[i]
    for k in range(n + m):
        out[k] = r[perm[k]]


@_jit
def active_set_solve(P_values: np.ndarray, P_rows: np.ndarray, P_cols: np.ndarray,
                     q: np.ndarray, A_values: np.ndarray, A_rows: np.ndarray,
                     A_cols: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                     z: np.ndarray, y: np.ndarray, K_source: np.ndarray, Kp: np.ndarray,
                     Ki: np.ndarray, Kx: np.ndarray, perm: np.ndarray, Lp: np.ndarray,
                     Li: np.ndarray, Lx: np.ndarray, D: np.ndarray, Dinv: np.ndarray,
                     Lnz: np.ndarray, etree: np.ndarray, iwork: np.ndarray,
                     fwork: np.ndarray, side: np.ndarray, delta: float, epsilon: float,
                     c: float, tau: float, max_iter: int, refinements: int
                     ) -> tuple[int, int]:
    r"""The primal-dual active-set iteration (module docstring) from the warm start
    ``(z (n,), y (m,))``, which it overwrites with the last iterate.

    ``P_values/P_rows/P_cols``: the upper triangle of :math:`P` as entries (row <= col);
    ``A_values/A_rows/A_cols``: :math:`A` as entries. The KKT matrix's permuted upper
    triangle has the fixed pattern ``(Kp, Ki)``; ``K_source`` says where each of its
    entries comes from: ``s < nP`` the ``P`` entry ``s`` (plus :math:`\delta` on the
    diagonal, the first ``n`` entries), ``nP <= s < nP + nA`` the ``A`` entry
    ``s - nP``, beyond the diagonal of row ``s - nP - nA``. ``perm (n+m,)``: position
    ``k`` of the permuted system holds unknown ``perm[k]``. ``Lp`` ... ``etree``: the
    factor's arrays (:func:`ldl_symbolic`); ``iwork (4(n+m),)``, ``fwork (3(n+m),)``,
    ``side (m,)`` (int8, the working set on return).

    Returns
    -------
    tuple[int, int]
        ``(status, iterations)``: :data:`ACTIVE_SET_CONVERGED`,
        :data:`ACTIVE_SET_MAX_ITER` or :data:`ACTIVE_SET_FACTOR_FAILED`; the
        factorizations made.
    """
    n = z.shape[0]
    m = y.shape[0]
    nk = n + m
    nP = P_values.shape[0]
    nA = A_values.shape[0]
    Az = np.empty(m)
    rhs = fwork[nk:2 * nk]
    sol = fwork[2 * nk:3 * nk]
    for i in range(m):
        Az[i] = 0.0
    for e in range(nA):
        Az[A_rows[e]] += A_values[e] * z[A_cols[e]]
    for i in range(m):
        side[i] = 0
    _working_set(Az, y, lower, upper, c, tau, side, True)
    for it in range(1, max_iter + 1):
        for k in range(Kx.shape[0]):
            s = K_source[k]
            if s < nP:
                Kx[k] = P_values[s] + (delta if s < n else 0.0)
            elif s < nP + nA:
                e = s - nP
                Kx[k] = A_values[e] if side[A_rows[e]] != 0 else 0.0
            else:
                Kx[k] = -epsilon if side[s - nP - nA] != 0 else -1.0
        if ldl_factor(Kp, Ki, Kx, Lp, Li, Lx, D, Dinv, Lnz, etree, iwork,
                      fwork[:nk]) < 0:
            return ACTIVE_SET_FACTOR_FAILED, it
        # the first solve from zero: the residual at (0, 0) is the right-hand side
        for j in range(n):
            z[j] = 0.0
        for i in range(m):
            y[i] = 0.0
        for _ in range(refinements + 1):
            _residual(P_values, P_rows, P_cols, q, A_values, A_rows, A_cols, lower, upper,
                      side, z, y, perm, rhs, Az, sol)
            ldl_solve(Lp, Li, Lx, Dinv, rhs)
            for k in range(nk):
                sol[perm[k]] = rhs[k]
            for j in range(n):
                z[j] += sol[j]
            for i in range(m):
                y[i] += sol[n + i]
        for j in range(n):
            if not math.isfinite(z[j]):
                return ACTIVE_SET_FACTOR_FAILED, it
        for i in range(m):
            Az[i] = 0.0
        for e in range(nA):
            Az[A_rows[e]] += A_values[e] * z[A_cols[e]]
        if not _working_set(Az, y, lower, upper, c, tau, side, False):
            return ACTIVE_SET_CONVERGED, it
    return ACTIVE_SET_MAX_ITER, max_iter


@_jit
def qp_residuals(P_values: np.ndarray, P_rows: np.ndarray, P_cols: np.ndarray, q: np.ndarray,
                 A_values: np.ndarray, A_rows: np.ndarray, A_cols: np.ndarray,
                 lower: np.ndarray, upper: np.ndarray, z: np.ndarray, y: np.ndarray
                 ) -> tuple[float, float, float]:
    r"""``(primal, dual, objective)`` at ``(z, y)``: :math:`\max_i \mathrm{dist}(a_i z,
    [l_i, u_i])`, :math:`\|Pz + q + A^\top y\|_\infty` and :math:`\tfrac12 z^\top P z +
    q^\top z` (``P`` as upper-triangle entries, ``A`` as entries, as
    :func:`active_set_solve` takes them)."""
    n = z.shape[0]
    m = y.shape[0]
    g = q.copy()
    objective = 0.0
    for j in range(n):
        objective += q[j] * z[j]
    for e in range(P_values.shape[0]):
        i, j, v = P_rows[e], P_cols[e], P_values[e]
        g[i] += v * z[j]
        if i != j:
            g[j] += v * z[i]
            objective += v * z[i] * z[j]
        else:
            objective += 0.5 * v * z[i] * z[i]
    Az = np.zeros(m)
    for e in range(A_values.shape[0]):
        Az[A_rows[e]] += A_values[e] * z[A_cols[e]]
        g[A_cols[e]] += A_values[e] * y[A_rows[e]]
    dual = 0.0
    for j in range(n):
        dual = max(dual, abs(g[j]))
    primal = 0.0
    for i in range(m):
        primal = max(primal, lower[i] - Az[i], Az[i] - upper[i])
    return primal, dual, objective


def warm_up_kkt() -> None:
    r"""Compile (or load) every kernel here with the signatures the active-set backend
    uses, on :math:`\min \tfrac12 z^2 + z` s.t. :math:`0 \le z \le 1`."""
    one = np.zeros(1, dtype=np.int64)
    Kp = np.array([0, 1, 3], dtype=np.int64)
    Ki = np.array([0, 0, 1], dtype=np.int64)
    source = np.arange(3, dtype=np.int64)
    etree = np.empty(2, dtype=np.int64)
    Lnz = np.empty(2, dtype=np.int64)
    iwork = np.empty(8, dtype=np.int64)
    nnz = ldl_symbolic(Kp, Ki, etree, Lnz, iwork)
    Lp = np.zeros(3, dtype=np.int64)
    Li = np.zeros(max(nnz, 1), dtype=np.int64)
    Lx = np.zeros(max(nnz, 1))
    z, y = np.zeros(1), np.zeros(1)
    active_set_solve(np.ones(1), one, one, np.ones(1), np.ones(1), one, one, np.zeros(1),
                     np.ones(1), z, y, source, Kp, Ki, np.zeros(3), np.arange(2), Lp, Li, Lx,
                     np.zeros(2), np.zeros(2), Lnz, etree, iwork, np.zeros(6),
                     np.zeros(1, dtype=np.int8), 1e-9, 1e-9, 10.0, 1e-7, 8, 1)
    qp_residuals(np.ones(1), one, one, np.ones(1), np.ones(1), one, one, np.zeros(1),
                 np.ones(1), z, y)
    b = np.ones(2)
    if ldl_factor(Kp, Ki, np.array([1.0, 1.0, -1.0]), Lp, Li, Lx, np.zeros(2), np.zeros(2),
                  Lnz, etree, iwork, np.zeros(2)) > 0:
        ldl_solve(Lp, Li, Lx, np.ones(2), b)
