r"""Run records, the metrics of ``metrics.json`` and the run output files.

A :class:`RunRecord` holds what a closed-loop run produced: the sample times
:math:`t_0, \dots, t_k`, the states :math:`\chi_j(t_i)` of every robot, the
applied inputs :math:`u_j(t_i)` (zero-order hold), and the controller
computation times. ``k`` may be smaller than the scenario's ``K`` when a run
was interrupted; everything here works on partial records, down to ``k = 0``
(initial states only, no input applied yet).

:func:`compute_metrics` evaluates the keys of the contract's section 3. With
:math:`p_j(t_i)` the position :math:`(x, y)` of robot ``j``, :math:`r_j(t)` its
reference and :math:`\bar d_{jl} = (d_j + d_l)/2` the required distance of the
pair :math:`(j, l)`:

.. math::

    D_{jl}(t_i) &= \lVert p_j(t_i) - p_l(t_i) \rVert, \qquad
    c_{jl}(t_i) = D_{jl}(t_i) - \bar d_{jl},

    \mathrm{RMS}_j &= \Bigl(\tfrac{1}{k+1} \textstyle\sum_{i=0}^{k}
        \lVert p_j(t_i) - r_j(t_i) \rVert^2\Bigr)^{1/2},

    J &= \sum_{i=0}^{k-1} \sum_j
        e_j(t_{i+1})^\top Q\, e_j(t_{i+1}) + u_j(t_i)^\top R\, u_j(t_i),
    \qquad e_j = r_j - p_j,

``min_distance`` / ``min_clearance`` are the minima of :math:`D` and
:math:`c` over every sample and pair, and ``collisions`` counts the
(sample, pair) with :math:`c < -10^{-6}`.

Solve times: ``solve_times`` has one column per controller (one for the
centralized scheme, one per robot for the decentralized scheme). The time of a
sample is the sum over the columns (the paper's Table 3 convention for the
decentralized scheme). ``per_robot_median_ms`` is the median of each robot's
column; with a single (central) controller every id maps to the median of
that one column, and ``controllers`` says how many columns there were.
These are wall times (``solve_times``): on a loaded machine they grow with the
load. When the record has the controllers' CPU times (``cpu_times``, thread
time), ``solve_time["cpu"]`` holds the same figures from them (``total_s``,
``median_ms``, ``p99_ms``, ``max_ms``, ``per_robot_median_ms``), and
``solve_time["load_average"]`` the 1/5/15-minute load averages at the run's
end with ``cpus`` the machine's logical CPUs (``None`` where not recorded).

Every value in the metrics dict is JSON-serializable: Python ``int``,
``float``, ``str``, ``bool``, ``None``, lists and dicts; non-finite floats
(and quantities that do not exist, e.g. distances of a single robot) are
``None``.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from sqpmpc.problem.goals import ARRIVAL_TOLERANCE
from sqpmpc.problem.paths import obstacle_clearances, plant_paths, segment_distances
from sqpmpc.problem.references import PointReference
from sqpmpc.problem.routes import route_lengths
from sqpmpc.sim.record import RunRecord

__all__ = [
    "ARRIVAL_TOLERANCE", "COLLISION_TOLERANCE", "BOUND_TOLERANCE", "RunRecord", "compute_metrics",
    "intersample_distances", "pair_distances",
]

log = logging.getLogger(__name__)

COLLISION_TOLERANCE = 1e-6
"""A (sample, pair) is a collision when its clearance is below ``-COLLISION_TOLERANCE``."""
BOUND_TOLERANCE = 1e-9
"""An input or position violates its bound when outside it by more than this."""


def pair_distances(positions: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    r"""Centre distances :math:`D_{jl}(t_i) = \lVert p_j(t_i) - p_l(t_i) \rVert`.

    Parameters
    ----------
    positions
        Shape ``(m, n, 2)``.
    pairs
        Index pairs, shape ``(P, 2)``.

    Returns
    -------
    np.ndarray
        Shape ``(m, P)``.
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    diff = positions[:, pairs[:, 0], :] - positions[:, pairs[:, 1], :]
    return np.linalg.norm(diff, axis=-1)


def intersample_distances(positions: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    r"""Smallest centre distance of each pair *between* consecutive samples.

    With the Euler model (the default plant) a robot moves on the straight
    segment from :math:`p(t_i)` to :math:`p(t_{i+1})` at constant speed, so
    the relative position of a pair is affine in time,
    :math:`r(s) = r_i + s\,(r_{i+1} - r_i)`, :math:`s \in [0, 1]`, and its
    smallest norm is at :math:`s^* = \mathrm{clip}(-r_i^\top \Delta r /
    \|\Delta r\|^2, 0, 1)`. Constraints imposed only at the samples (paper
    eq. 5) allow two robots to pass *through* each other between samples;
    this measures it. For an RK4 plant the segment is the chord of the arc.

    Parameters
    ----------
    positions
        Shape ``(m, n, 2)``, ``m >= 1``.
    pairs
        Index pairs, shape ``(P, 2)``.

    Returns
    -------
    np.ndarray
        Shape ``(m - 1, P)``: the minimum over each interval (endpoints included).
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    r = positions[:, pairs[:, 0], :] - positions[:, pairs[:, 1], :]
    return segment_distances(r[:-1], r[1:])


def _between_samples(piece_distances: np.ndarray, k: int) -> np.ndarray:
    """Per-interval minimum ``(k, P)`` of the distances of the path pieces ``(k M, P)``."""
    M = piece_distances.shape[0] // k
    return piece_distances.reshape((k, M) + piece_distances.shape[1:]).min(axis=1)


def _no_route(sc: Any, ids: np.ndarray) -> list[int]:
    """Ids of the robots with a goal at rest that no route through the static map reaches
    from their initial positions (:func:`sqpmpc.problem.routes.route_lengths`)."""
    static = bool(getattr(sc, "polygons", ())) or any(
        not o.moving for o in getattr(sc, "obstacles", ()))
    if not static:
        return []
    goals = np.asarray(sc.reference_positions(sc.t_end), dtype=float)
    lengths = route_lengths(sc, goals)
    return [int(i) for i, r, length in zip(ids, sc.robots, lengths, strict=True)
            if isinstance(r.reference, PointReference) and length is None]


def _float(x: Any) -> float | None:
    """A Python float, or ``None`` for NaN / infinity / missing."""
    if x is None:
        return None
    v = float(x)
    return v if math.isfinite(v) else None


def _jsonable(obj: Any) -> Any:
    """Recursively convert numpy scalars/arrays and non-finite floats for JSON."""
    if isinstance(obj, dict):
        return {str(key): _jsonable(v) for key, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    if isinstance(obj, bool | int | str) or obj is None:
        return obj
    if isinstance(obj, float):
        return _float(obj)
    if isinstance(obj, Path):
        return str(obj)
    return str(obj)


def _solve_time_metrics(record: RunRecord, ids: np.ndarray) -> dict[str, Any]:
    out = _time_metrics(record.solve_times, ids)
    out["clock"] = "wall"
    if record.cpu_times is not None:
        out["cpu"] = _time_metrics(record.cpu_times, ids)
        out["cpu"]["clock"] = "thread CPU time"
    load = record.extra.get("load_average")
    out["load_average"] = None if load is None else [_float(v) for v in load]
    out["cpus"] = record.extra.get("cpus")
    return out


def _time_metrics(st: np.ndarray, ids: np.ndarray) -> dict[str, Any]:
    """Sum, median, p99 and maximum per sample (ms) and per-robot medians of ``st (k, c)``."""
    per_sample = st.sum(axis=1)
    if per_sample.size == 0:
        median = p99 = peak = None
    else:
        median = _float(np.median(per_sample) * 1e3)
        p99 = _float(np.percentile(per_sample, 99) * 1e3)
        peak = _float(per_sample.max() * 1e3)
    if st.shape[0] == 0:
        column_medians: list[float | None] = [None] * st.shape[1]
    else:
        column_medians = [_float(v * 1e3) for v in np.median(st, axis=0)]
    if st.shape[1] == 1:
        column_medians = column_medians * len(ids)
    return {
        "total_s": _float(per_sample.sum()),
        "median_ms": median,
        "p99_ms": p99,
        "max_ms": peak,
        "per_robot_median_ms": {str(i): m for i, m in zip(ids, column_medians, strict=True)},
        "controllers": int(st.shape[1]),
    }


def compute_metrics(record: RunRecord) -> dict[str, Any]:
    """Evaluate the metrics of ``metrics.json`` (contract section 3) on a record.

    Parameters
    ----------
    record
        A complete or partial run record.

    Returns
    -------
    dict
        JSON-serializable metrics: the contract's keys (``scenario``,
        ``scheme``, ``steps``, ``sample_time``, ``horizon``, ``min_distance``,
        ``min_clearance``, ``collisions``, ``rms_tracking_error``,
        ``closed_loop_cost``, ``input_bound_violations``, ``solver_failures``,
        ``solve_time``) plus ``completed``, ``planned_steps``, ``ids``,
        ``min_clearance_at`` (``{"t", "pair"}`` of the minimum),
        ``final_position_error`` (per robot id, m, at the last sample against the
        reference then), ``max_final_position_error``, ``arrived`` (per robot id:
        final error <= :data:`ARRIVAL_TOLERANCE`), ``all_arrived``,
        ``arrival_tolerance``, ``state_bound_violations``, ``intersample_min_clearance`` and
        ``intersample_collisions`` (the same between samples, see
        :func:`intersample_distances`; ``None``/0 before the first step) and
        the record's ``extra`` entries (an
        extra key that clashes with one of these is stored as
        ``"extra.<key>"``). ``steps`` is the number ``k`` of samples actually
        simulated. Without any pair (one robot) ``min_distance``,
        ``min_clearance`` and ``min_clearance_at`` are ``None`` and
        ``collisions`` is 0.
    """
    sc = record.scenario
    ids = record.ids
    k = record.k
    pos = record.positions
    ref = record.references()

    # The true paths between samples (arcs of an exact plant), then pairwise distances
    # and clearances over every sample and between samples.
    path_t, path_pos = plant_paths(record.states, record.plant_inputs
                                   if record.plant_inputs is not None else record.inputs,
                                   float(sc.sample_time), record.plant_model,
                                   bool(getattr(sc.bounds, "dynamic_limits", False)))
    pairs = np.asarray(sc.pairs(), dtype=np.int64).reshape(-1, 2)
    min_distance = min_clearance = None
    min_at: dict[str, Any] | None = None
    collisions = intersample_collisions = 0
    intersample_min_clearance = None
    if pairs.shape[0] > 0:
        dist = pair_distances(pos, pairs)
        required = np.asarray(sc.required_distances(), dtype=float)[pairs[:, 0], pairs[:, 1]]
        clearance = dist - required
        min_distance = _float(dist.min())
        min_clearance = _float(clearance.min())
        collisions = int(np.count_nonzero(clearance < -COLLISION_TOLERANCE))
        if k > 0:
            between = _between_samples(intersample_distances(path_pos, pairs), k) - required
            intersample_min_clearance = _float(between.min())
            intersample_collisions = int(np.count_nonzero(between < -COLLISION_TOLERANCE))
        if min_clearance is not None:
            i, p = np.unravel_index(int(np.argmin(clearance)), clearance.shape)
            min_at = {"t": _float(record.t[i]),
                      "pair": [int(ids[pairs[p, 0]]), int(ids[pairs[p, 1]])]}

    # Tracking.
    err = np.linalg.norm(pos - ref, axis=-1)  # (k+1, n)
    rms = np.sqrt(np.mean(err**2, axis=0))
    final = err[-1]

    # Closed-loop cost of the executed trajectory.
    q = np.asarray(sc.weights.Q, dtype=float).reshape(2)
    r = np.asarray(sc.weights.R, dtype=float).reshape(2)
    e_next = ref[1:] - pos[1:]
    cost = float(np.sum(e_next**2 * q) + np.sum(record.inputs**2 * r))

    # Bound violations.
    lo_u = np.asarray(sc.bounds.input_lower(), dtype=float).reshape(2)
    hi_u = np.asarray(sc.bounds.input_upper(), dtype=float).reshape(2)
    u = record.inputs
    input_violations = int(np.count_nonzero(
        (u < lo_u - BOUND_TOLERANCE) | (u > hi_u + BOUND_TOLERANCE)))
    lo_p = np.asarray(sc.bounds.position_lower(), dtype=float).reshape(2)
    hi_p = np.asarray(sc.bounds.position_upper(), dtype=float).reshape(2)
    state_violations = int(np.count_nonzero(
        (pos < lo_p - BOUND_TOLERANCE) | (pos > hi_p + BOUND_TOLERANCE)))

    metrics: dict[str, Any] = {
        "scenario": str(sc.name),
        "scheme": str(record.scheme),
        "steps": k,
        "sample_time": _float(sc.sample_time),
        "horizon": int(sc.horizon),
        "min_distance": min_distance,
        "min_clearance": min_clearance,
        "collisions": collisions,
        "rms_tracking_error": {str(i): _float(v) for i, v in zip(ids, rms, strict=True)},
        "closed_loop_cost": _float(cost),
        "input_bound_violations": input_violations,
        "solver_failures": int(record.solver_failures),
        "solve_time": _solve_time_metrics(record, ids),
        "completed": bool(record.completed),
        "planned_steps": int(sc.steps),
        "ids": [int(i) for i in ids],
        "min_clearance_at": min_at,
        "final_position_error": {str(i): _float(v) for i, v in zip(ids, final, strict=True)},
        "max_final_position_error": _float(final.max()),
        "arrived": {str(i): bool(v <= ARRIVAL_TOLERANCE) for i, v in zip(ids, final,
                                                                         strict=True)},
        "all_arrived": bool(np.all(final <= ARRIVAL_TOLERANCE)),
        "arrival_tolerance": ARRIVAL_TOLERANCE,
        "state_bound_violations": state_violations,
        "intersample_min_clearance": intersample_min_clearance,
        "intersample_collisions": intersample_collisions,
        **obstacle_clearances(sc, record.t, pos, path_t, path_pos, COLLISION_TOLERANCE),
        "no_route": _no_route(sc, ids),
    }
    plant = getattr(sc, "plant", None)
    if plant is not None:
        metrics["plant"] = plant.to_dict()
        if record.plant_inputs is not None and k > 0:
            noise = record.plant_inputs - record.inputs
            metrics["plant"]["applied_noise_max"] = [_float(v) for v in
                                                    np.abs(noise).max(axis=(0, 1))]
    for key, value in (record.extra or {}).items():
        name = str(key)
        if name in metrics:
            log.warning("extra metric %r clashes with a standard key; stored as 'extra.%s'",
                        name, name)
            name = f"extra.{name}"
        metrics[name] = value
    return _jsonable(metrics)


