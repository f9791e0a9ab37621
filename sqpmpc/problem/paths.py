r"""The robots' true paths between samples, and the clearances measured along them.

A record holds the states at the samples and the inputs the plant applied.
Between samples an Euler (or RK4) plant moves on the straight chord at
constant speed; an exact plant moves on the arc of the held input, which
:func:`plant_paths` samples at :data:`ARC_SUBSTEPS` points per sample with the
closed-form step (:func:`sqpmpc.models.unicycle.discrete_dynamics` with a fraction of
:math:`T_s`). The clearances between samples are then the smallest distances
of consecutive path points moving straight (:func:`sqpmpc.problem.paths.segment_distances`);
for an arc that chord of a sub-arc is within :math:`|v\omega|(T_s/M)^2/8` of it
(:math:`5 \cdot 10^{-5}` m for the paper's bounds at :math:`T_s` = 1 s and
:math:`M` = 32).

:func:`obstacle_clearances` measures every robot against every obstacle at
the samples and along the paths (the obstacles move straight at constant
velocity), and every static polygon (:func:`sqpmpc.problem.polygons.polygon_clearances`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sqpmpc.models.acceleration import acceleration_dynamics
from sqpmpc.models.unicycle import discrete_dynamics
from sqpmpc.problem.obstacles import obstacle_positions
from sqpmpc.problem.polygons import polygon_clearances

__all__ = ["ARC_SUBSTEPS", "obstacle_clearances", "plant_paths", "segment_distances"]

#: Points per sample at which an exact plant's arcs are measured.
ARC_SUBSTEPS = 32


def plant_paths(states: np.ndarray, applied_inputs: np.ndarray | None, sample_time: float,
                plant_model: str, velocity_states: bool = False
                ) -> tuple[np.ndarray, np.ndarray]:
    r"""Positions along the true paths and their times.

    Parameters
    ----------
    states
        ``(k+1, n, 3)`` at the samples.
    applied_inputs
        ``(k, n, 2)`` the inputs the plant applied (with its noise), or ``None``.
    sample_time
        :math:`T_s`.
    plant_model
        ``"euler"``, ``"rk4"`` (chords) or ``"exact"`` (arcs).
    velocity_states
        The robots had acceleration limits (:class:`sqpmpc.problem.plant.Plant` with
        bounds): ``applied_inputs`` are the velocities reached at each sample's end
        (zero before the first), the velocity changes linearly over a sample and
        the path is sampled at :data:`ARC_SUBSTEPS` points per sample (the speed
        varies along a chord too).

    Returns
    -------
    tuple of np.ndarray
        Times ``(k M + 1,)`` and positions ``(k M + 1, n, 2)``, ``M = 1`` for
        chords, :data:`ARC_SUBSTEPS` for arcs. Every sample is one of the points.
    """
    k = states.shape[0] - 1
    if velocity_states and applied_inputs is not None and k > 0:
        return _accelerated_paths(states, applied_inputs, sample_time, plant_model)
    if plant_model != "exact" or applied_inputs is None or k == 0:
        return sample_time * np.arange(k + 1), states[..., :2]
    M = ARC_SUBSTEPS
    frac = np.arange(M) / M  # (M,)
    pts = np.empty((k, M) + states.shape[1:2] + (2,))
    for j, f in enumerate(frac):
        if j == 0:
            pts[:, 0] = states[:-1, :, :2]
        else:
            pts[:, j] = discrete_dynamics(states[:-1], applied_inputs, f * sample_time,
                                          "exact")[..., :2]
    positions = np.concatenate((pts.reshape((k * M,) + pts.shape[2:]), states[-1:, :, :2]))
    t = sample_time * np.concatenate((np.repeat(np.arange(k), M) + np.tile(frac, k), [k]))
    return t, positions


def _accelerated_paths(states: np.ndarray, reached: np.ndarray, sample_time: float,
                       plant_model: str) -> tuple[np.ndarray, np.ndarray]:
    """:func:`plant_paths` of robots with velocity states (linear velocity changes)."""
    k = states.shape[0] - 1
    M = ARC_SUBSTEPS
    start = np.concatenate((np.zeros((1,) + reached.shape[1:]), reached[:-1]))
    accel = (reached - start) / sample_time
    full = np.concatenate((states[:-1, :, :3], start), axis=-1)
    frac = np.arange(M) / M
    pts = np.empty((k, M) + states.shape[1:2] + (2,))
    pts[:, 0] = states[:-1, :, :2]
    for j in range(1, M):
        pts[:, j] = acceleration_dynamics(full, accel, frac[j] * sample_time,
                                          plant_model)[..., :2]
    positions = np.concatenate((pts.reshape((k * M,) + pts.shape[2:]), states[-1:, :, :2]))
    t = sample_time * np.concatenate((np.repeat(np.arange(k), M) + np.tile(frac, k), [k]))
    return t, positions


def obstacle_clearances(scenario: Any, t: np.ndarray, positions: np.ndarray,
                        path_t: np.ndarray, path_positions: np.ndarray,
                        tolerance: float) -> dict[str, Any]:
    """``obstacle_collisions`` and ``min_obstacle_clearance`` (contract section 1b).

    Parameters
    ----------
    scenario
        With ``obstacles`` and ``diameters()``.
    t, positions
        Samples ``(k+1,)`` and ``(k+1, n, 2)``.
    path_t, path_positions
        The true paths (:func:`plant_paths`).
    tolerance
        A clearance below ``-tolerance`` is a collision.

    Returns
    -------
    dict
        ``obstacle_collisions``: (sample, robot, obstacle) and (interval,
        robot, obstacle) entries inside the distance; ``min_obstacle_clearance``
        over both (``None`` without obstacles); ``intersample_min_obstacle_clearance``.
    """
    obstacles = tuple(getattr(scenario, "obstacles", ()))
    polygons = tuple(getattr(scenario, "polygons", ()))
    if not obstacles and not polygons:
        return {"obstacle_collisions": 0, "min_obstacle_clearance": None,
                "intersample_min_obstacle_clearance": None}
    if not obstacles:
        return _polygons_only(scenario, polygons, positions, path_positions, tolerance)
    d = np.asarray(scenario.diameters(), dtype=float)
    d_o = np.array([o.diameter for o in obstacles])
    need = 0.5 * (d[:, None] + d_o[None, :])  # (n, O)
    at = obstacle_positions(obstacles, t)  # (k+1, O, 2)
    gap = positions[:, :, None, :] - at[:, None, :, :]
    clearance = np.hypot(gap[..., 0], gap[..., 1]) - need
    collisions = int(np.count_nonzero(clearance < -tolerance))
    best = float(clearance.min())
    between = None
    if positions.shape[0] > 1:
        along = obstacle_positions(obstacles, path_t)  # (S, O, 2)
        rel = path_positions[:, :, None, :] - along[:, None, :, :]  # (S, n, O, 2)
        piece = segment_distances(rel[:-1], rel[1:]) - need  # (S-1, n, O)
        pieces_per_sample = (path_t.shape[0] - 1) // (positions.shape[0] - 1)
        per_interval = piece.reshape((positions.shape[0] - 1, pieces_per_sample)
                                     + piece.shape[1:]).min(axis=1)
        between = float(per_interval.min())
        collisions += int(np.count_nonzero(per_interval < -tolerance))
        best = min(best, between)
    if polygons:
        more = _polygons_only(scenario, polygons, positions, path_positions, tolerance)
        collisions += more["obstacle_collisions"]
        best = min(best, more["min_obstacle_clearance"])
        if between is not None:
            between = min(between, more["intersample_min_obstacle_clearance"])
    return {"obstacle_collisions": collisions, "min_obstacle_clearance": best,
            "intersample_min_obstacle_clearance": between}


def _polygons_only(scenario: Any, polygons: tuple[Any, ...], positions: np.ndarray,
                   path_positions: np.ndarray, tolerance: float) -> dict[str, Any]:
    """:func:`obstacle_clearances` of the polygon obstacles alone."""
    radii = 0.5 * np.asarray(scenario.diameters(), dtype=float)
    collisions, at, between = polygon_clearances(
        polygons, radii, positions, path_positions if positions.shape[0] > 1 else None,
        tolerance)
    best = at if between is None else min(at, between)  # type: ignore[type-var]
    return {"obstacle_collisions": collisions, "min_obstacle_clearance": best,
            "intersample_min_obstacle_clearance": between}


def segment_distances(start: np.ndarray, end: np.ndarray) -> np.ndarray:
    r"""Smallest norm of :math:`r(s) = r_0 + s\,(r_1 - r_0)` over :math:`s \in [0, 1]`.

    For relative positions of two robots that move on straight segments at
    constant speed over a sample (the Euler model), this is their smallest
    distance during the sample; for a point and a segment, the point-segment
    distance. The minimizer is :math:`s^* = \mathrm{clip}(-r_0^\top \Delta r /
    \|\Delta r\|^2, 0, 1)`.

    Parameters
    ----------
    start, end
        ``(..., 2)`` relative positions at the start and the end of the sample.

    Returns
    -------
    np.ndarray
        ``(...)`` the smallest distances.
    """
    dr = end - start
    den = _dot(dr, dr)
    num = -_dot(start, dr)
    s = np.clip(np.divide(num, den, out=np.zeros_like(den), where=den > 0.0), 0.0, 1.0)
    closest = start + s[..., None] * dr
    return np.hypot(closest[..., 0], closest[..., 1])


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products of 2-D vectors ``(..., 2)`` (broadcast)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]
