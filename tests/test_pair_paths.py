"""The centralized check of a pair's exact relative path under constant accelerations
(:mod:`sqpmpc.kernels.pair_paths`): sound against dense sampling, and it accepts what the
per-robot disc refused (a robot at rest just outside its distance moving along the gap)."""

from __future__ import annotations

import numpy as np

from sqpmpc.kernels.acceleration import pairs_keep_bulging_distance
from sqpmpc.kernels.pair_paths import pairs_keep_ramp_distance, quartic_nonnegative, ramp_vectors

PAIR = np.array([[0, 1]], dtype=np.int64)


def _true_margin(now: np.ndarray, nxt: np.ndarray, ramp: np.ndarray, alpha: np.ndarray,
                 beta: np.ndarray, required: float) -> float:
    """Smallest ``|r(s)| - g(s) - required`` on a dense grid of s."""
    s = np.linspace(0.0, 1.0, 20001)[:, None]
    r0 = now[0] - now[1]
    r = r0 + s * ((nxt[0] - nxt[1]) - r0) - s * (1.0 - s) * (ramp[0] - ramp[1])
    ramp_len = np.linalg.norm(ramp, axis=1).sum()
    a, b = alpha.sum(), beta.sum() - ramp_len
    g = a * s[:, 0] + b * s[:, 0] * (1.0 - s[:, 0])
    return float((np.linalg.norm(r, axis=1) - g - required).min())


def test_quartic_nonnegative_proves_and_refuses() -> None:
    assert quartic_nonnegative(1.0, -4.0, 6.0, -4.0, 1.0 + 1e-3)   # (1 - s)^4 + 1e-3 s^4
    assert quartic_nonnegative(0.0, 0.0, 1.0, 0.0, 0.0)            # s^2, zero at s = 0
    assert not quartic_nonnegative(0.01, 0.0, -1.0, 0.0, 0.0)      # negative inside
    assert not quartic_nonnegative(-1e-12, 0.0, 1.0, 0.0, 0.0)     # negative at s = 0


def test_the_ramp_check_never_accepts_a_path_that_comes_closer() -> None:
    rng = np.random.default_rng(7)
    accepted = 0
    for _ in range(400):
        now = rng.normal(size=(2, 2))
        nxt = now + 0.3 * rng.normal(size=(2, 2))
        ramp = ramp_vectors(rng.uniform(-np.pi, np.pi, 2), rng.uniform(-2.0, 2.0, 2), 0.5)
        gamma = rng.uniform(0.0, 0.01, 2)
        alpha = gamma + rng.uniform(0.0, 0.01, 2)
        beta = np.linalg.norm(ramp, axis=1) - gamma
        required = float(np.linalg.norm(now[0] - now[1]) - rng.uniform(0.0, 0.2))
        if pairs_keep_ramp_distance(PAIR, now, nxt, ramp, np.array([required]), alpha, beta):
            accepted += 1
            assert _true_margin(now, nxt, ramp, alpha, beta, required) >= -1e-9
    assert accepted > 50


def test_a_robot_at_rest_just_outside_may_move_along_the_gap() -> None:
    required = 0.5
    now = np.array([[0.0, 0.0], [required + 0.0026, 0.0]])
    ramp = ramp_vectors(np.array([np.pi / 2, 0.0]), np.array([2.0, 0.0]), 0.5)  # robot 0: +y
    nxt = now + np.array([[0.0, 0.25], [0.0, 0.0]])                               # from rest
    alpha = np.zeros(2)
    beta = np.linalg.norm(ramp, axis=1)
    keep = np.array([required])
    assert not pairs_keep_bulging_distance(PAIR, now, nxt, keep, alpha, beta)
    assert pairs_keep_ramp_distance(PAIR, now, nxt, ramp, keep, alpha, beta)
    # towards the other robot it is still refused
    closer = now + np.array([[0.25, 0.0], [0.0, 0.0]])
    towards = ramp_vectors(np.array([0.0, 0.0]), np.array([2.0, 0.0]), 0.5)
    assert not pairs_keep_ramp_distance(PAIR, now, closer, towards, keep, alpha,
                                        np.linalg.norm(towards, axis=1))
