r"""Compiled kernels of the per-sample hot path (numba, cached on disk).

Every kernel works on plain float arrays and writes its results into arrays
the caller owns (views into the QP's value arrays where possible), so a
sample makes a handful of kernel calls instead of hundreds of small NumPy
operations. The arithmetic is the same as the NumPy reference implementations
in :mod:`sqpmpc.models.unicycle` (tested against them); the collision rows and checks
are in :mod:`sqpmpc.kernels.collision`, which :func:`warm_up` covers too.

Compilation happens once per machine: ``cache=True`` stores the machine code
next to this file (``__pycache__``), and :func:`warm_up` compiles or loads
every kernel at controller construction, so neither the real-time loop nor a
service's first sample pays for it. ``python -m sqpmpc.kernels`` prints the
time :func:`warm_up` takes (on a fresh install it compiles, later it loads).

Conventions: positions are ``(x, y)``, states ``(x, y, psi)``, inputs
``(v, omega)``; ``N`` is the horizon; a QP robot block is laid out
``(chi_0, u_0, chi_1, ..., u_{N-1}, chi_N)`` (see :mod:`sqpmpc.qp.layout`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "all_finite",
    "clip_and_roll_out",
    "clip_bounds",
    "euler_defect_l1",
    "MULTIPLIER_SCALE",
    "kkt_residual",
    "measure_sample",
    "shift_iterate",
    "shift_plan",
    "split_rows",
    "write_reference",
    "rows_shortfall",
    "euler_linearize",
    "euler_rollout",
    "euler_step",
    "headings_jump",
    "within_box",
]

_jit = numba.njit(cache=True, nogil=True)


@_jit
def all_finite(values: np.ndarray) -> bool:
    """Whether every entry of the 1-D array ``values`` is finite (no NaN, no inf)."""
    for v in values:
        if not math.isfinite(v):
            return False
    return True


@_jit
def within_box(points: np.ndarray, low: np.ndarray, high: np.ndarray) -> bool:
    """Whether every point ``(m, 2)`` satisfies ``low <= p <= high`` (``(2,)`` each; NaN
    fails), the comparisons of ``((points >= low) & (points <= high)).all()``."""
    for i in range(points.shape[0]):
        for k in range(points.shape[1]):
            if not (points[i, k] >= low[k] and points[i, k] <= high[k]):
                return False
    return True


@_jit
def headings_jump(headings: np.ndarray, last: np.ndarray) -> bool:
    """Whether some ``|headings[i] - last[i]| > pi`` (a wrapped yaw to move by whole turns,
    :func:`sqpmpc.models.base.continuous_headings`)."""
    for i in range(headings.shape[0]):
        if abs(headings[i] - last[i]) > math.pi:
            return True
    return False


@_jit
def measure_sample(states: np.ndarray, indices: np.ndarray, measured: np.ndarray,
                   last: np.ndarray, known: bool, positions: np.ndarray, headings: np.ndarray,
                   own: np.ndarray) -> int:
    """The measurement's checks and copies in one call.

    Returns ``-1`` when some entry of ``states (n, k)`` is not finite. Else copies the own
    robots' rows ``states[indices]`` into ``measured (m, k)``, ``states[:, :2]``,
    ``states[:, 2]`` and the own poses ``measured[:, :3]`` into ``positions``, ``headings``
    and ``own``, and returns ``1`` when some measured heading is more than pi from ``last``
    (``known``: ``last`` holds the previous sample's; a wrapped yaw, see
    :func:`headings_jump`), else ``0`` with the measured headings copied into ``last``.
    """
    for i in range(states.shape[0]):
        for j in range(states.shape[1]):
            if not math.isfinite(states[i, j]):
                return -1
    for r in range(indices.shape[0]):
        for j in range(states.shape[1]):
            measured[r, j] = states[indices[r], j]
    for i in range(states.shape[0]):
        positions[i, 0], positions[i, 1], headings[i] = states[i, 0], states[i, 1], states[i, 2]
    for i in range(measured.shape[0]):
        own[i, 0], own[i, 1], own[i, 2] = measured[i, 0], measured[i, 1], measured[i, 2]
    if known:
        for i in range(measured.shape[0]):
            if abs(measured[i, 2] - last[i]) > math.pi:
                return 1
    for i in range(measured.shape[0]):
        last[i] = measured[i, 2]
    return 0


@_jit
def clip_bounds(lower: np.ndarray, upper: np.ndarray, infinity: float, lower_out: np.ndarray,
                upper_out: np.ndarray) -> None:
    """``lower``/``upper`` clipped to ``[-infinity, infinity]`` (OSQP's infinity) into the outs."""
    for i in range(lower.shape[0]):
        lower_out[i] = max(lower[i], -infinity)
        upper_out[i] = min(upper[i], infinity)


@_jit
def euler_step(states: np.ndarray, inputs: np.ndarray, h: float, out: np.ndarray) -> None:
    r"""Euler step (paper eq. 3) of ``(K, 3)`` states under ``(K, 2)`` inputs into ``out``.

    :math:`x^+ = x + (T_s v)\cos\psi`, :math:`y^+ = y + (T_s v)\sin\psi`,
    :math:`\psi^+ = \psi + T_s\omega`.
    """
    for k in range(states.shape[0]):
        psi = states[k, 2]
        hv = h * inputs[k, 0]
        out[k, 0] = states[k, 0] + hv * math.cos(psi)
        out[k, 1] = states[k, 1] + hv * math.sin(psi)
        out[k, 2] = psi + h * inputs[k, 1]


@_jit
def euler_rollout(initial: np.ndarray, inputs: np.ndarray, h: float, out: np.ndarray) -> None:
    """States ``out (m, N+1, 3)`` of applying ``inputs (m, N, 2)`` from ``initial (m, 3)``.

    Step by step, exactly as :func:`euler_step` (and so as the Euler plant).
    """
    m, N = inputs.shape[0], inputs.shape[1]
    for r in range(m):
        x, y, psi = initial[r, 0], initial[r, 1], initial[r, 2]
        out[r, 0, 0], out[r, 0, 1], out[r, 0, 2] = x, y, psi
        for i in range(N):
            hv = h * inputs[r, i, 0]
            x = x + hv * math.cos(psi)
            y = y + hv * math.sin(psi)
            psi = psi + h * inputs[r, i, 1]
            out[r, i + 1, 0], out[r, i + 1, 1], out[r, i + 1, 2] = x, y, psi


@_jit
def shift_plan(states: np.ndarray, inputs: np.ndarray, h: float, out: np.ndarray) -> None:
    """Stages 1..N ``out (N, 3)`` at sample ``k`` from a plan ``(N+1, 3)``, ``(N, 2)`` of ``k-1``.

    Stages 1..N-1 are the plan's stages 2..N; stage N holds its last input for
    one more Euler step.
    """
    N = out.shape[0]
    for i in range(N - 1):
        out[i, 0], out[i, 1], out[i, 2] = states[i + 2, 0], states[i + 2, 1], states[i + 2, 2]
    psi = states[N, 2]
    hv = h * inputs[N - 1, 0]
    out[N - 1, 0] = states[N, 0] + hv * math.cos(psi)
    out[N - 1, 1] = states[N, 1] + hv * math.sin(psi)
    out[N - 1, 2] = psi + h * inputs[N - 1, 1]


@_jit
def clip_and_roll_out(initial: np.ndarray, inputs: np.ndarray, lower: np.ndarray,
                      upper: np.ndarray, h: float, out: np.ndarray) -> bool:
    """Clip the first input of ``inputs (m, N, 2)`` to its bounds in place, then roll out.

    Returns ``False`` (and rolls nothing out) if any input is not finite;
    otherwise ``out (m, N+1, 3)`` holds :func:`euler_rollout` of the clipped plan.
    """
    for r in range(inputs.shape[0]):
        for i in range(inputs.shape[1]):
            for j in range(2):
                if not math.isfinite(inputs[r, i, j]):
                    return False
        for j in range(2):
            inputs[r, 0, j] = min(max(inputs[r, 0, j], lower[j]), upper[j])
    euler_rollout(initial, inputs, h, out)
    return True


@_jit
def split_rows(A_values: np.ndarray, lower: np.ndarray, upper: np.ndarray,
               eq_entries: np.ndarray, g_entries: np.ndarray, g_rows: np.ndarray,
               eq_rows: np.ndarray, ineq_rows: np.ndarray, free: float, infinity: float,
               A_eq_data: np.ndarray, G_data: np.ndarray, b: np.ndarray, h_l: np.ndarray,
               h_u: np.ndarray) -> None:
    r"""The QP's rows as equalities :math:`A_e z = b` and inequalities
    :math:`h_l \le G z \le h_u` (PIQP's form), values written into the given arrays.

    ``eq_entries``/``g_entries`` map each CSC entry of :math:`A_e`/:math:`G` to
    its entry in ``A_values``; ``g_rows`` is the row (in :math:`G`) of each
    entry of :math:`G`. A row with both bounds beyond ``free`` is off: its
    entries become 0 and its bounds :math:`[-1, 1]`; other bounds are clipped to
    ``infinity``.
    """
    for e in range(eq_entries.shape[0]):
        A_eq_data[e] = A_values[eq_entries[e]]
    for r in range(eq_rows.shape[0]):
        b[r] = upper[eq_rows[r]]
    for r in range(ineq_rows.shape[0]):
        lo, up = lower[ineq_rows[r]], upper[ineq_rows[r]]
        if lo <= -free and up >= free:
            h_l[r], h_u[r] = -1.0, 1.0
        else:
            h_l[r], h_u[r] = max(lo, -infinity), min(up, infinity)
    for e in range(g_entries.shape[0]):
        r = ineq_rows[g_rows[e]]
        off = lower[r] <= -free and upper[r] >= free
        G_data[e] = 0.0 if off else A_values[g_entries[e]]


@_jit
def write_reference(q: np.ndarray, reference: np.ndarray, scale: np.ndarray,
                    block: int, stage: int) -> None:
    r"""Linear cost of the positions of stages 1..N: :math:`q_p = -2 Q_r r` into ``q``.

    ``reference (m, N, 2)``; ``scale (m, 1, 2)`` holds :math:`-2 Q_r` per robot;
    a robot's block has ``block`` variables, a stage ``stage`` (``nx + nu``),
    the position first.
    """
    for r in range(reference.shape[0]):
        for i in range(reference.shape[1]):
            k = r * block + stage * (i + 1)
            q[k] = scale[r, 0, 0] * reference[r, i, 0]
            q[k + 1] = scale[r, 0, 1] * reference[r, i, 1]


@_jit
def shift_iterate(z: np.ndarray, y: np.ndarray, z_order: np.ndarray, y_order: np.ndarray,
                  m: int, N: int, block: int, h: float, z_out: np.ndarray,
                  y_out: np.ndarray) -> None:
    """Iterate and multipliers shifted by one stage (gathers ``z_order``, ``y_order``).

    The new last state of each robot is the Euler step of its old last state
    under its held last input.
    """
    for i in range(z_order.shape[0]):
        z_out[i] = z[z_order[i]]
    for i in range(y_order.shape[0]):
        y_out[i] = y[y_order[i]]
    for r in range(m):
        last = r * block + 5 * N
        psi = z[last + 2]
        hv = h * z[last - 2]
        z_out[last] = z[last] + hv * math.cos(psi)
        z_out[last + 1] = z[last + 1] + hv * math.sin(psi)
        z_out[last + 2] = psi + h * z[last - 1]


@_jit
def euler_linearize(z: np.ndarray, m: int, N: int, block: int, h: float,
                    dyn_A: np.ndarray, dyn_B: np.ndarray, dyn_lower: np.ndarray,
                    dyn_upper: np.ndarray) -> None:
    r"""Euler linearization at ``z`` written into the QP's dynamics values.

    Row block :math:`\chi_{i+1} - A_i\chi_i - B_i u_i = c_i` with
    :math:`A_i = I + T_s\,\partial f/\partial\chi`, :math:`B_i = T_s\,\partial f/\partial u`
    and :math:`c_i = T_s\bar v\bar\psi(\sin\bar\psi, -\cos\bar\psi, 0)`.
    ``dyn_A``/``dyn_B`` receive ``-A``/``-B`` at the pattern entries
    (:data:`sqpmpc.qp.layout.A_PATTERN`, ``B_PATTERN``), ``(m N 5,)`` each;
    ``dyn_lower``/``dyn_upper`` ``(m N 3,)`` receive ``c``.
    """
    for r in range(m):
        for i in range(N):
            base = r * block + i * 5
            psi = z[base + 2]
            hv = h * z[base + 3]
            c = math.cos(psi)
            s = math.sin(psi)
            k = (r * N + i) * 5
            dyn_A[k] = -1.0
            dyn_A[k + 1] = -1.0
            dyn_A[k + 2] = -1.0
            dyn_A[k + 3] = -((-hv) * s)
            dyn_A[k + 4] = -(hv * c)
            dyn_B[k] = -(h * c)
            dyn_B[k + 1] = -0.0
            dyn_B[k + 2] = -(h * s)
            dyn_B[k + 3] = -0.0
            dyn_B[k + 4] = -h
            hvpsi = hv * psi
            j = (r * N + i) * 3
            c0 = hvpsi * s
            c1 = (-hvpsi) * c
            dyn_lower[j] = c0
            dyn_upper[j] = c0
            dyn_lower[j + 1] = c1
            dyn_upper[j + 1] = c1
            dyn_lower[j + 2] = 0.0
            dyn_upper[j + 2] = 0.0


@_jit
def euler_defect_l1(z: np.ndarray, initial: np.ndarray, m: int, N: int, block: int,
                    h: float) -> float:
    r"""L1 norm of the Euler dynamics defects and of the initial-state defect at ``z``.

    :math:`\sum_i \|\chi_{i+1} - f_d(\chi_i, u_i)\|_1 + \|\chi_0 - \chi(k)\|_1`
    over the own robots (the merit function's nonlinear constraints).
    """
    total = 0.0
    for r in range(m):
        base = r * block
        for k in range(3):
            total += abs(z[base + k] - initial[r, k])
        for i in range(N):
            b = base + 5 * i
            psi = z[b + 2]
            hv = h * z[b + 3]
            total += abs(z[b + 5] - (z[b] + hv * math.cos(psi)))
            total += abs(z[b + 6] - (z[b + 1] + hv * math.sin(psi)))
            total += abs(z[b + 7] - (psi + h * z[b + 4]))
    return total


@_jit
def rows_shortfall(A_values: np.ndarray, entries: np.ndarray, entry_rows: np.ndarray,
                   entry_cols: np.ndarray, z: np.ndarray, lower: np.ndarray,
                   rows: np.ndarray, scratch: np.ndarray) -> float:
    """``sum_j max(l_j - (A z)_j, 0)`` over the rows ``rows``, from their entries of ``A``."""
    scratch[:] = 0.0
    for k in range(entries.shape[0]):
        scratch[entry_rows[k]] += A_values[entries[k]] * z[entry_cols[k]]
    total = 0.0
    for j in range(rows.shape[0]):
        total += max(lower[rows[j]] - scratch[j], 0.0)
    return total


#: IPOPT's :math:`s_{max}` (Wächter and Biegler 2006, eq. 6): multipliers up to this mean
#: size leave the KKT residual unscaled.
MULTIPLIER_SCALE = 100.0


@_jit
def kkt_residual(A_values: np.ndarray, A_rows: np.ndarray, A_cols: np.ndarray,
                 z: np.ndarray, y: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                 P_diag: np.ndarray, q: np.ndarray, Az: np.ndarray, ATy: np.ndarray) -> float:
    r"""Scaled KKT residual of :math:`\min \tfrac12 z^\top \mathrm{diag}(P) z + q^\top z`,
    :math:`l \le Az \le u` at ``(z, y)`` (OSQP's sign convention).

    The largest of the stationarity :math:`\|Pz + q + A^\top y\|_\infty / s`, the
    primal violation, the complementarity :math:`|y_i|\,\mathrm{dist}_i / s` on
    finite bounds and any multiplier pushing against an infinite bound, with
    IPOPT's multiplier scaling (Wächter and Biegler 2006, eq. 6)

    .. math::

        s = \max\left(1, \frac{\|y\|_1}{s_{max}\, m}\right), \qquad
        s_{max} = 100,

    :math:`m` the rows. Multipliers of mean size up to :math:`s_{max}` leave the
    residual unscaled (:math:`s = 1`); larger ones (rows nearly parallel to the
    motion they stop, priced in thousands) make a stationarity error of
    :math:`|y|\,\|\Delta z\|` from steps at the QP's resolution, which no
    iteration removes, so it is measured relative to them. The primal
    violation is never scaled.
    """
    Az[:] = 0.0
    ATy[:] = 0.0
    for k in range(A_values.shape[0]):
        a = A_values[k]
        Az[A_rows[k]] += a * z[A_cols[k]]
        ATy[A_cols[k]] += a * y[A_rows[k]]
    size = 0.0
    for i in range(y.shape[0]):
        size += abs(y[i])
    scale = max(1.0, size / (MULTIPLIER_SCALE * max(y.shape[0], 1)))
    dual = 0.0
    for j in range(z.shape[0]):
        dual = max(dual, abs(P_diag[j] * z[j] + q[j] + ATy[j]))
    worst = 0.0
    for i in range(Az.shape[0]):
        lo, up, ax, yi = lower[i], upper[i], Az[i], y[i]
        worst = max(worst, lo - ax, ax - up)
        if yi < 0.0:
            if math.isfinite(lo):
                dual = max(dual, abs(-yi * (ax - lo)))
            else:
                worst = max(worst, -yi)
        elif yi > 0.0:
            if math.isfinite(up):
                dual = max(dual, abs(yi * (up - ax)))
            else:
                worst = max(worst, yi)
    return max(worst, dual / scale)
