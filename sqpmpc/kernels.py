r"""Compiled kernels of the per-sample hot path (numba, cached on disk).

Every kernel works on plain float arrays and writes its results into arrays
the caller owns (views into the QP's value arrays where possible), so a
sample makes a handful of kernel calls instead of hundreds of small NumPy
operations. The arithmetic is the same as the NumPy reference implementations
in :mod:`sqpmpc.model` and :mod:`sqpmpc.collision` (tested against them).

Compilation happens once per machine: ``cache=True`` stores the machine code
next to this file (``__pycache__``), and :func:`warm_up` compiles or loads
every kernel at controller construction, so neither the real-time loop nor a
service's first sample pays for it. ``python -m sqpmpc.kernels`` prints the
time :func:`warm_up` takes (on a fresh install it compiles, later it loads).

Conventions: positions are ``(x, y)``, states ``(x, y, psi)``, inputs
``(v, omega)``; ``N`` is the horizon; a QP robot block is laid out
``(chi_0, u_0, chi_1, ..., u_{N-1}, chi_N)`` (see :mod:`sqpmpc.layout`).
"""

from __future__ import annotations

import math
import time

import numba
import numpy as np

from .liveness import hold_touching_rows, limit_turning, warm_up_rules
from .references import _harmonic_positions
from .roundabout import warm_up_roundabout

__all__ = [
    "all_finite",
    "clip_and_roll_out",
    "clip_bounds",
    "halfplanes_hold",
    "segment_keeps_distance",
    "euler_defect_l1",
    "kkt_residual",
    "nearest_within",
    "obstacle_rows",
    "shift_iterate",
    "stage_one_override",
    "shift_plan",
    "split_rows",
    "write_reference",
    "rows_shortfall",
    "euler_linearize",
    "euler_rollout",
    "euler_step",
    "pair_rows",
    "select_pairs",
    "pairs_keep_distance",
    "shared_rows",
    "warm_up",
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
def halfplanes_hold(normals: np.ndarray, rhs: np.ndarray, x: float, y: float,
                    tolerance: float) -> bool:
    """Whether the point ``(x, y)`` satisfies every ``normals[e] . p >= rhs[e] - tolerance``."""
    for e in range(normals.shape[0]):
        if normals[e, 0] * x + normals[e, 1] * y < rhs[e] - tolerance:
            return False
    return True


@_jit
def segment_keeps_distance(x0: float, y0: float, x1: float, y1: float, points: np.ndarray,
                           keep: np.ndarray, tolerance: float) -> bool:
    r"""Whether the segment :math:`(x_0, y_0) \to (x_1, y_1)` keeps ``keep[u] - tolerance``
    from every ``points[u]`` (the point-segment distance, as
    :func:`sqpmpc.collision.segment_distances`)."""
    dx, dy = x1 - x0, y1 - y0
    den = dx * dx + dy * dy
    for u in range(points.shape[0]):
        rx, ry = x0 - points[u, 0], y0 - points[u, 1]
        s = 0.0
        if den > 0.0:
            s = min(max(-(rx * dx + ry * dy) / den, 0.0), 1.0)
        if math.hypot(rx + s * dx, ry + s * dy) < keep[u] - tolerance:
            return False
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
                    block: int) -> None:
    r"""Linear cost of the positions of stages 1..N: :math:`q_p = -2 Q_r r` into ``q``.

    ``reference (m, N, 2)``; ``scale (m, 1, 2)`` holds :math:`-2 Q_r` per robot.
    """
    for r in range(reference.shape[0]):
        for i in range(reference.shape[1]):
            k = r * block + 5 * (i + 1)
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
    (:data:`sqpmpc.layout.A_PATTERN`, ``B_PATTERN``), ``(m N 5,)`` each;
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
def _unit(dx: float, dy: float, fx: float, fy: float) -> tuple[float, float]:
    """``(dx, dy) / |(dx, dy)|``, or the fallback ``(fx, fy)`` below 1e-9 m."""
    d = math.hypot(dx, dy)
    if d > 1e-9:
        return dx / d, dy / d
    return fx, fy


@_jit
def _stage_normals(gx: float, gy: float, a_pred: np.ndarray, b_pred: np.ndarray,
                   rotation: np.ndarray, max_turn: float, normals: np.ndarray
                   ) -> tuple[float, float]:
    """Stage normals ``(N, 2)`` of a pair: Taylor normals, turn limit, rotation.

    ``(gx, gy)`` is the current offset (this robot minus the other),
    ``a_pred``/``b_pred`` ``(N, 2+)`` the predicted positions of stages 1..N,
    ``rotation (N, 2)`` the per-stage ``(cos, sin)`` of the keep-right tilt
    and ``max_turn < 0`` skips the turn limit. Returns the current unit normal.
    """
    n0x, n0y = _unit(gx, gy, 1.0, 0.0)
    N = normals.shape[0]
    for i in range(N):
        nx, ny = _unit(a_pred[i, 0] - b_pred[i, 0], a_pred[i, 1] - b_pred[i, 1], n0x, n0y)
        normals[i, 0], normals[i, 1] = nx, ny
    if max_turn >= 0.0:
        limit_turning(n0x, n0y, normals, max_turn)
    for i in range(N):
        c, s = rotation[i, 0], rotation[i, 1]
        x, y = normals[i, 0], normals[i, 1]
        normals[i, 0] = x * c + y * (-s)
        normals[i, 1] = x * s + y * c
    return n0x, n0y


@_jit
def stage_one_override(normals: np.ndarray, n0x: float, n0y: float, gx: float, gy: float,
                       d: float) -> tuple[float, int]:
    r"""The ``stage-one-override`` safety row, in place on ``normals (N, 2)``.

    If the stage-1 normal does not keep the current offset ``(gx, gy)`` at
    ``d`` (:math:`n_1^\top g < d`), it is replaced by the current unit normal
    ``(n0x, n0y)``, so that standing still satisfies stage 1. Returns the
    projected current gap :math:`n_1^\top g` and 1 if the row was overridden.
    """
    gap = normals[0, 0] * gx + normals[0, 1] * gy
    if gap >= d:
        return gap, 0
    normals[0, 0], normals[0, 1] = n0x, n0y
    return n0x * gx + n0y * gy, 1


@_jit
def pair_rows(pairs: np.ndarray, now: np.ndarray, states: np.ndarray, required: np.ndarray,
              rotation: np.ndarray, max_turn: float, A_out: np.ndarray,
              lower_out: np.ndarray, normals: np.ndarray, stages: np.ndarray) -> int:
    r"""Centralized pair rows :math:`n^\top(p_a - p_b) \ge d` into the QP (stages 1..N).

    Parameters
    ----------
    pairs
        ``(P, 2)`` local robot indices.
    now
        ``(m, 2)`` measured positions (the stage-1 safety rule).
    states
        ``(m, N+1, 3)`` linearization point.
    required
        ``(P,)`` required distances plus margin.
    rotation, max_turn
        Keep-right ``(N, 2)`` (cos, sin) per stage; turn limit (``< 0``: none).
    A_out, lower_out
        ``(P, N, 4)`` values ``(n, -n)`` and ``(P, N)`` right-hand sides.
    normals
        ``(N, 2)`` scratch.
    stages
        ``(P,)`` how many stages of each pair get a row (``N``: all, ``1``: the
        first only, ``0``: none); the other rows are off (zero normal, ``-inf``).

    Returns
    -------
    int
        Rows whose stage-1 normal was replaced by the current one (stage-1 rule).
    """
    overrides = 0
    N = normals.shape[0]
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        for i in range(stages[p], N):
            A_out[p, i, 0] = A_out[p, i, 1] = A_out[p, i, 2] = A_out[p, i, 3] = 0.0
            lower_out[p, i] = -np.inf
        if stages[p] == 0:
            continue
        gx, gy = now[a, 0] - now[b, 0], now[a, 1] - now[b, 1]
        n0x, n0y = _stage_normals(gx, gy, states[a, 1:], states[b, 1:], rotation, max_turn,
                                  normals)
        d = required[p]
        gap, overridden = stage_one_override(normals, n0x, n0y, gx, gy, d)
        overrides += overridden
        for i in range(stages[p]):
            nx, ny = normals[i, 0], normals[i, 1]
            A_out[p, i, 0], A_out[p, i, 1] = nx, ny
            A_out[p, i, 2], A_out[p, i, 3] = -nx, -ny
            lower_out[p, i] = d
        lower_out[p, 0] = min(d, gap)
    return overrides


@_jit
def select_pairs(pairs: np.ndarray, positions: np.ndarray, radius: np.ndarray, slots: int,
                 horizon: int, stages_out: np.ndarray) -> tuple[int, int]:
    r"""The centralized form of the neighbour slots: how many stages each pair gets.

    A pair farther apart than its ``radius`` (required distance plus margin
    plus :math:`2 v_{max} N T_s`) cannot come within its distance over the
    horizon: no row (0). Each robot's ``slots`` nearest pairs within the radius
    get every stage (``horizon``); a pair within the radius that neither robot
    chose keeps its stage-1 row (1), so the next sample keeps its distance
    whatever the plan after it (the first-input check covers every pair).

    Parameters
    ----------
    pairs
        ``(P, 2)`` robot indices.
    positions
        ``(m, 2)`` measured positions.
    radius
        ``(P,)`` interaction radii.
    slots, horizon
        The budget per robot and ``N``.
    stages_out
        ``(P,)`` output.

    Returns
    -------
    tuple of int
        Pairs with every stage, pairs with stage 1 only.
    """
    P = pairs.shape[0]
    m = positions.shape[0]
    dist = np.empty(P)
    degree = np.zeros(m, dtype=np.int64)
    for p in range(P):
        a, b = pairs[p, 0], pairs[p, 1]
        dist[p] = math.hypot(positions[a, 0] - positions[b, 0], positions[a, 1] - positions[b, 1])
        near = dist[p] <= radius[p]
        stages_out[p] = 1 if near else 0
        if near:
            degree[a] += 1
            degree[b] += 1
    start = np.zeros(m + 1, dtype=np.int64)
    for r in range(m):
        start[r + 1] = start[r] + degree[r]
    members = np.empty(start[m], dtype=np.int64)
    fill = start[:m].copy()
    for p in range(P):
        if stages_out[p]:
            for r in (pairs[p, 0], pairs[p, 1]):
                members[fill[r]] = p
                fill[r] += 1
    for r in range(m):
        mine = members[start[r]:start[r + 1]]
        order = np.argsort(dist[mine], kind="mergesort")
        for s in range(min(slots, mine.shape[0])):
            stages_out[mine[order[s]]] = horizon
    full = 0
    first = 0
    for p in range(P):
        full += stages_out[p] == horizon
        first += stages_out[p] == 1
    return full, first


@_jit
def shared_rows(me: np.ndarray, others_now: np.ndarray, own_pred: np.ndarray,
                other_pred: np.ndarray, shared: np.ndarray, required: np.ndarray,
                true_distance: np.ndarray, rotation: np.ndarray, max_turn: float,
                A_out: np.ndarray, lower_out: np.ndarray, check_normals: np.ndarray,
                check_rhs: np.ndarray, touching: np.ndarray) -> int:
    r"""Shared-responsibility rows of one robot against its neighbours (decentralized).

    For every slot ``e`` with ``shared[e]``: the common hyperplane of the two
    exchanged predictions, half the distance each (see
    :class:`sqpmpc.collision.ExternalCollisionModel`), with the stage-1 offset
    clipped so that both current positions stay on their sides. Other slots
    get zero normals and ``-inf`` bounds (no constraint).

    Parameters
    ----------
    me, others_now
        ``(2,)`` and ``(E, 2)`` measured positions.
    own_pred, other_pred
        ``(N, 2+)`` and ``(E, N, 2+)`` predicted positions of stages 1..N.
    shared
        ``(E,)`` bool.
    required, true_distance
        ``(E,)`` distances with and without the margin.
    rotation, max_turn
        As in :func:`pair_rows`.
    A_out, lower_out
        ``(E, N, 2)`` normals and ``(E, N)`` right-hand sides of the rows.
    check_normals, check_rhs
        ``(E, 2)``, ``(E,)``: the first-stage check of the true distance
        (``n^T p >= rhs``); ``-inf`` for slots that are not shared.
    touching
        ``(E,)`` bool out: the pair is inside the margin band.

    Returns
    -------
    int
        Stage-1 normals replaced by the current one.
    """
    overrides = 0
    E, N = shared.shape[0], A_out.shape[1]
    mx, my = me[0], me[1]
    for e in range(E):
        touching[e] = False
        if not shared[e]:
            for i in range(N):
                A_out[e, i, 0] = 0.0
                A_out[e, i, 1] = 0.0
                lower_out[e, i] = -np.inf
            check_normals[e, 0] = 0.0
            check_normals[e, 1] = 0.0
            check_rhs[e] = -np.inf
            continue
        ox, oy = others_now[e, 0], others_now[e, 1]
        gx, gy = mx - ox, my - oy
        n = A_out[e]
        n0x, n0y = _stage_normals(gx, gy, own_pred, other_pred[e], rotation, max_turn, n)
        d = required[e]
        half = 0.5 * d
        gap, overridden = stage_one_override(n, n0x, n0y, gx, gy, d)
        overrides += overridden
        for i in range(N):
            cx = 0.5 * (own_pred[i, 0] + other_pred[e, i, 0])
            cy = 0.5 * (own_pred[i, 1] + other_pred[e, i, 1])
            lower_out[e, i] = n[i, 0] * cx + n[i, 1] * cy
        n1x, n1y = n[0, 0], n[0, 1]
        lo = (n1x * ox + n1y * oy) + half
        n1_me = n1x * mx + n1y * my
        hi = n1_me - half
        c0 = min(max(lower_out[e, 0], lo), max(lo, hi))
        lower_out[e, 0] = c0
        for i in range(N):
            lower_out[e, i] = lower_out[e, i] + half
        lower_out[e, 0] = min(lower_out[e, 0], n1_me)
        touching[e] = gap < d
        D = true_distance[e]
        check_normals[e, 0], check_normals[e, 1] = n1x, n1y
        if gap >= d:
            check_rhs[e] = c0 + 0.5 * D
        else:
            mid = n1x * (0.5 * (mx + ox)) + n1y * (0.5 * (my + oy))
            check_rhs[e] = mid + 0.5 * min(D, gap)
    return overrides


@_jit
def obstacle_rows(me: np.ndarray, others_now: np.ndarray, own: np.ndarray,
                  obstacles: np.ndarray, kinds: np.ndarray, required: np.ndarray,
                  reach: float, rotation: np.ndarray, stage_one_rule: bool,
                  A_out: np.ndarray, lower_out: np.ndarray) -> int:
    r"""Rows of the obstacle (kind 2) and missing (kind 3) slots at the own iterate.

    Each such neighbour's prediction is a moving obstacle: the full distance
    :math:`n^	op p \ge n^	op o + d` with :math:`n` the rotated unit direction
    from the obstacle to the own predicted position (``own (N, 2+)``, stages
    1..N). With ``stage_one_rule`` a stage-1 normal that the current positions
    violate is replaced by the current one (``stage-one-override``). Missing
    slots then get the ``missing-neighbour-reach`` stage-1 row: keep
    :math:`d + r` from the neighbour's current position if the current gap
    allows, else do not approach. Other slots are left as they are. Returns
    the number of stage-1 overrides.
    """
    overrides = 0
    N = A_out.shape[1]
    mx, my = me[0], me[1]
    for e in range(kinds.shape[0]):
        if kinds[e] != 2 and kinds[e] != 3:
            continue
        gx, gy = mx - others_now[e, 0], my - others_now[e, 1]
        n0x, n0y = _unit(gx, gy, 1.0, 0.0)
        d = required[e]
        for i in range(N):
            nx, ny = _unit(own[i, 0] - obstacles[e, i, 0], own[i, 1] - obstacles[e, i, 1],
                           n0x, n0y)
            c, sn = rotation[i, 0], rotation[i, 1]
            A_out[e, i, 0] = nx * c - ny * sn
            A_out[e, i, 1] = nx * sn + ny * c
        if stage_one_rule:
            overrides += stage_one_override(A_out[e], n0x, n0y, gx, gy, d)[1]
        for i in range(N):
            lower_out[e, i] = (A_out[e, i, 0] * obstacles[e, i, 0]
                               + A_out[e, i, 1] * obstacles[e, i, 1]) + d
        if kinds[e] == 3:
            keep = d + reach
            A_out[e, 0, 0], A_out[e, 0, 1] = n0x, n0y
            if n0x * gx + n0y * gy >= keep:
                lower_out[e, 0] = (n0x * others_now[e, 0] + n0y * others_now[e, 1]) + keep
            else:
                lower_out[e, 0] = n0x * mx + n0y * my
    return overrides


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


@_jit
def kkt_residual(A_values: np.ndarray, A_rows: np.ndarray, A_cols: np.ndarray,
                 z: np.ndarray, y: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                 P_diag: np.ndarray, q: np.ndarray, Az: np.ndarray, ATy: np.ndarray) -> float:
    r"""KKT residual of :math:`\min 	frac12 z^	op \mathrm{diag}(P) z + q^	op z`,
    :math:`l \le Az \le u` at ``(z, y)`` (OSQP's sign convention).

    The largest of the stationarity :math:`\|Pz + q + A^	op y\|_\infty`, the
    primal violation, the complementarity :math:`|y_i|\,\mathrm{dist}_i` on
    finite bounds and any multiplier pushing against an infinite bound.
    """
    Az[:] = 0.0
    ATy[:] = 0.0
    for k in range(A_values.shape[0]):
        a = A_values[k]
        Az[A_rows[k]] += a * z[A_cols[k]]
        ATy[A_cols[k]] += a * y[A_rows[k]]
    worst = 0.0
    for j in range(z.shape[0]):
        worst = max(worst, abs(P_diag[j] * z[j] + q[j] + ATy[j]))
    for i in range(Az.shape[0]):
        lo, up, ax, yi = lower[i], upper[i], Az[i], y[i]
        worst = max(worst, lo - ax, ax - up)
        if yi < 0.0:
            worst = max(worst, abs(-yi * (ax - lo)) if math.isfinite(lo) else -yi)
        elif yi > 0.0:
            worst = max(worst, abs(yi * (up - ax)) if math.isfinite(up) else yi)
    return worst


@_jit
def pairs_keep_distance(pairs: np.ndarray, now: np.ndarray, nxt: np.ndarray,
                        required: np.ndarray) -> bool:
    r"""Whether every pair keeps ``required`` along the straight segments of one sample.

    With both robots moving on straight segments at constant speed, the
    relative position is :math:`r(s) = r_0 + s(r_1 - r_0)`, whose smallest norm
    on :math:`s\in[0,1]` is at :math:`s^* = \mathrm{clip}(-r_0^\top\Delta/\|\Delta\|^2)`.
    """
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        r0x, r0y = now[a, 0] - now[b, 0], now[a, 1] - now[b, 1]
        dx = (nxt[a, 0] - nxt[b, 0]) - r0x
        dy = (nxt[a, 1] - nxt[b, 1]) - r0y
        den = dx * dx + dy * dy
        s = 0.0
        if den > 0.0:
            s = min(max(-(r0x * dx + r0y * dy) / den, 0.0), 1.0)
        if math.hypot(r0x + s * dx, r0y + s * dy) < required[p]:
            return False
    return True



@_jit
def nearest_within(me: np.ndarray, positions: np.ndarray, others: np.ndarray,
                   radius: np.ndarray, chosen_out: np.ndarray, rest_out: np.ndarray
                   ) -> tuple[int, int]:
    r"""The robots ``others`` within ``radius`` of ``me``, nearest first (stable order).

    ``positions (n, 2)`` are everyone's, ``others (m,)`` the candidates'
    indices into them and ``radius (m,)`` their radii. The first
    ``len(chosen_out)`` of them, as indices into ``others``, go to
    ``chosen_out``, the rest to ``rest_out (m,)``. Returns both counts.
    """
    m = others.shape[0]
    dist = np.empty(m)
    near = np.empty(m, dtype=np.int64)
    count = 0
    for e in range(m):
        j = others[e]
        d = math.hypot(positions[j, 0] - me[0], positions[j, 1] - me[1])
        if d <= radius[e]:
            near[count] = e
            dist[count] = d
            count += 1
    order = np.argsort(dist[:count], kind="mergesort")
    used = min(chosen_out.shape[0], count)
    for s in range(used):
        chosen_out[s] = near[order[s]]
    for s in range(used, count):
        rest_out[s - used] = near[order[s]]
    return used, count - used


def warm_up() -> float:
    """Compile (first time on a machine) or load every kernel; returns the seconds taken."""
    t0 = time.perf_counter()
    all_finite(np.zeros(3))
    clip_bounds(np.zeros(3), np.zeros(3), 1e30, np.zeros(3), np.zeros(3))
    x = np.zeros((2, 3))
    u = np.zeros((2, 2))
    euler_step(x, u, 0.1, np.empty((2, 3)))
    euler_rollout(x, np.zeros((2, 2, 2)), 0.1, np.empty((2, 3, 3)))
    shift_plan(np.zeros((3, 3)), np.zeros((2, 2)), 0.1, np.empty((2, 3)))
    clip_and_roll_out(x, np.zeros((2, 2, 2)), -np.ones(2), np.ones(2), 0.1, np.empty((2, 3, 3)))
    halfplanes_hold(np.zeros((1, 2)), np.zeros(1), 0.0, 0.0, 1e-12)
    segment_keeps_distance(0.0, 0.0, 1.0, 0.0, np.ones((1, 2)), np.ones(1), 1e-12)
    one = np.zeros(1, dtype=np.int64)
    split_rows(np.ones(2), np.zeros(2), np.ones(2), one, one + 1, one, one, one + 1, 1e20, 1e30,
               np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1))
    z = np.zeros(2 * 13)
    euler_linearize(z, 2, 2, 13, 0.1, np.empty(20), np.empty(20), np.empty(12), np.empty(12))
    rot = np.tile([1.0, 0.0], (2, 1))
    pairs = np.array([[0, 1]], dtype=np.int64)
    states = np.zeros((2, 3, 3))
    states[1, :, 0] = 1.0
    stages = np.full(1, 2, dtype=np.int64)
    pair_rows(pairs, x[:, :2].copy(), states, np.ones(1), rot, 0.6, np.empty((1, 2, 4)),
              np.empty((1, 2)), np.empty((2, 2)), stages)
    select_pairs(pairs, x[:, :2].copy(), np.ones(1), 1, 2, stages)
    pairs_keep_distance(pairs, x[:, :2].copy(), x[:, :2].copy(), np.ones(1))
    touching = np.zeros(1, dtype=np.bool_)
    A = np.empty((1, 2, 2))
    lo = np.empty((1, 2))
    shared_rows(np.zeros(2), np.ones((1, 2)), np.zeros((2, 3)), np.ones((1, 2, 3)),
                np.ones(1, dtype=np.bool_), np.ones(1), np.ones(1), rot, 0.6, A, lo,
                np.empty((1, 2)), np.empty(1), touching)
    hold_touching_rows(np.zeros(2), touching, A, lo)
    obstacle_rows(np.zeros(2), np.ones((1, 2)), np.zeros((2, 3)), np.ones((1, 2, 3)),
                  np.full(1, 3, dtype=np.int8), np.ones(1), 0.1, rot, True, A, lo)
    euler_defect_l1(z, x, 2, 2, 13, 0.1)
    idx = np.zeros(2, dtype=np.int64)
    nearest_within(np.zeros(2), np.ones((3, 2)), np.arange(1, 3), np.full(2, 5.0), idx[:1],
                   idx.copy())
    write_reference(z, np.zeros((2, 2, 2)), np.zeros((2, 1, 2)), 13)
    order = np.arange(26)
    shift_iterate(z, z, order, order, 2, 2, 13, 0.1, np.empty(26), np.empty(26))
    idx = np.zeros(1, dtype=np.int64)
    rows_shortfall(np.ones(3), idx, idx, idx, z, np.ones(3), idx, np.zeros(1))
    kkt_residual(np.ones(1), idx, idx, z, np.ones(3), np.ones(3), np.ones(3), z, z,
                 np.zeros(3), np.zeros(26))
    warm_up_rules()
    warm_up_roundabout()
    _harmonic_positions(np.ones((2, 7)), np.zeros(3), np.empty((2, 3, 2)))
    return time.perf_counter() - t0


if __name__ == "__main__":
    print(f"sqpmpc kernels ready in {warm_up():.3f} s")
