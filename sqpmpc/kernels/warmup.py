"""Compile (first time on a machine) or load every compiled kernel of the package.

``python -m sqpmpc.kernels`` runs :func:`warm_up` (the README's first step).
"""

from __future__ import annotations

import time

import numpy as np

from sqpmpc.kernels import collision as ck
from sqpmpc.kernels.acceleration import warm_up_acceleration
from sqpmpc.kernels.execution import warm_up_execution
from sqpmpc.kernels.kkt import warm_up_kkt
from sqpmpc.kernels.lacam import warm_up_lacam
from sqpmpc.kernels.mapf import warm_up_mapf
from sqpmpc.kernels.motion import warm_up_motion
from sqpmpc.kernels.ocp import (
    all_finite,
    clip_and_roll_out,
    clip_bounds,
    euler_defect_l1,
    euler_linearize,
    euler_rollout,
    euler_step,
    headings_jump,
    kkt_residual,
    measure_sample,
    rows_shortfall,
    shift_iterate,
    shift_plan,
    split_rows,
    within_box,
    write_reference,
)
from sqpmpc.kernels.pair_paths import warm_up_pair_paths
from sqpmpc.kernels.polygons import path_keeps_pieces, piece_distances, polygon_rows
from sqpmpc.kernels.references import harmonic_positions
from sqpmpc.kernels.rings import warm_up_rings
from sqpmpc.kernels.rules import hold_touching_rows, inside_pairs, warm_up_roundabout, warm_up_rules

__all__ = ["warm_up"]


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


def warm_up() -> float:
    """Compile (first time on a machine) or load every kernel; returns the seconds taken."""
    t0 = time.perf_counter()
    # every call as the pipeline makes it: its arrays read-only where it passes views of
    # frozen data (the models' bounds, the rules' sample view, a decoded message), so that
    # no sample compiles a specialization (tests/test_kernel_warmup.py)
    all_finite(np.zeros(3))
    all_finite(_read_only(np.zeros(3)))
    headings_jump(np.zeros(2), np.zeros(2))
    headings_jump(np.zeros((2, 3))[:, 2], np.zeros(2))  # the measured poses' column
    # measured states: the simulation's, a decoded message's (read-only), a strided view
    for measured in (np.zeros((2, 3)), _read_only(np.zeros((2, 3))), np.zeros((2, 5))[:, :3]):
        measure_sample(measured, np.zeros(1, dtype=np.int64), np.empty((1, 3)), np.zeros(1),
                       True, np.empty((2, 2)), np.empty(2), np.empty((1, 3)))
    plan = np.zeros((2, 3, 3))
    within_box(plan[:, 1, :2], -np.ones(2), np.ones(2))  # a stage of a plan (strided)
    within_box(np.zeros((2, 2)), -np.ones(2), np.ones(2))
    clip_bounds(np.zeros(3), np.zeros(3), 1e30, np.zeros(3), np.zeros(3))
    x = np.zeros((2, 3))
    u = np.zeros((2, 2))
    euler_step(x, u, 0.1, np.empty((2, 3)))
    euler_rollout(x, np.zeros((2, 2, 2)), 0.1, np.empty((2, 3, 3)))
    shift_plan(np.zeros((3, 3)), np.zeros((2, 2)), 0.1, np.empty((2, 3)))
    clip_and_roll_out(x, np.zeros((2, 2, 2)), -np.ones(2), np.ones(2), 0.1, np.empty((2, 3, 3)))
    clip_and_roll_out(x, np.zeros((2, 2, 2)), _read_only(-np.ones(2)), _read_only(np.ones(2)),
                      0.1, np.empty((2, 3, 3)))
    ck.halfplanes_hold(np.zeros((1, 2)), np.zeros(1), 0.0, 0.0, 1e-12)
    ck.halfplanes_hold_path(np.zeros((1, 2)), np.zeros(1), 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1e-12)
    ck.segment_keeps_distance(0.0, 0.0, 1.0, 0.0, np.ones((1, 2)), np.ones(1), 1e-12, 0.0)
    ck.moving_points_keep_distance(0.0, 0.0, 1.0, 0.0, np.ones((1, 2)), np.ones((1, 2)),
                                   np.ones(1), 0.0)
    ck.moving_points_keep_distance(0.0, 0.0, 1.0, 0.0, np.ones((1, 2)), np.ones((1, 2)),
                                   np.ones(1), 0.0, 1e-3)
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
    ck.pair_rows(pairs, x[:, :2].copy(), states, np.ones(1), rot, 0.6, np.empty((1, 2, 4)),
              np.empty((1, 2)), np.empty((2, 2)), stages)
    ck.select_pairs(pairs, x[:, :2].copy(), np.ones(1), 1, 2, stages)
    ck.pairs_keep_distance(pairs, x[:, :2].copy(), x[:, :2].copy(), np.ones(1), np.zeros(2))
    ck.pairs_keep_distance(pairs, x[:, :2].copy(), x[:, :2].copy(), np.ones(1), np.zeros(2),
                           1e-3)
    touching = np.zeros(1, dtype=np.bool_)
    A = np.empty((1, 2, 2))
    lo = np.empty((1, 2))
    for me in (np.zeros(2), _read_only(np.zeros(2))):
        ck.shared_rows(me, np.ones((1, 2)), np.zeros((1, 2, 3)), np.ones((1, 2, 3)),
                       np.ones(1, dtype=np.bool_), np.ones(1), np.ones(1), rot, 0.6, A, lo,
                       np.empty((1, 2)), np.empty(1), touching)
        hold_touching_rows(me, touching, A, lo)
        inside_pairs(me, np.ones((1, 2)), np.ones(1, dtype=np.bool_), np.ones(1),
                     np.zeros(1, dtype=np.bool_))
        ck.obstacle_rows(me, np.ones((1, 2)), np.zeros((2, 3)), np.ones((1, 2, 3)),
                         np.full(1, 3, dtype=np.int8), np.ones(1), np.full(1, 0.1), rot, True,
                         A, lo)
    euler_defect_l1(z, x, 2, 2, 13, 0.1)
    idx = np.zeros(2, dtype=np.int64)
    ck.nearest_within(np.zeros(2), np.ones((3, 2)), np.arange(1, 3), np.full(2, 5.0), idx[:1],
                   idx.copy())
    write_reference(z, np.zeros((2, 2, 2)), np.zeros((2, 1, 2)), 13, 5)
    references = np.zeros((2, 2, 2))
    references.setflags(write=False)  # as the pipeline passes them (the rules' view)
    write_reference(z, references, np.zeros((2, 1, 2)), 13, 5)
    order = np.arange(26)
    shift_iterate(z, z, order, order, 2, 2, 13, 0.1, np.empty(26), np.empty(26))
    idx = np.zeros(1, dtype=np.int64)
    rows_shortfall(np.ones(3), idx, idx, idx, z, np.ones(3), idx, np.zeros(1))
    kkt_residual(np.ones(1), idx, idx, z, np.ones(3), np.ones(3), np.ones(3), z, z,
                 np.zeros(3), np.zeros(26))
    warm_up_rules()
    warm_up_acceleration()
    warm_up_pair_paths()
    warm_up_roundabout()
    warm_up_rings()
    warm_up_mapf()
    warm_up_execution()
    warm_up_motion()
    warm_up_lacam()
    warm_up_kkt()
    harmonic_positions(np.ones((2, 7)), np.zeros(3), np.empty((2, 3, 2)))
    square = np.array([[[1.0, 1.0], [2.0, 1.0], [2.0, 2.0], [1.0, 2.0]]])
    four = np.full(1, 4, dtype=np.int64)
    polygon_rows(np.zeros(2), np.zeros((2, 3)), square, four, np.ones(1), rot,
                 np.empty((1, 2, 2)), np.empty((1, 2)))
    path_keeps_pieces(0.0, 0.0, 0.1, 0.0, square, four, np.ones(1), 0.0)
    piece_distances(0.0, 0.0, square, four, np.empty(1))
    return time.perf_counter() - t0
