"""Unicycle model: Jacobians and Hessians against finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.errors import ProblemError
from sqpmpc.models.unicycle import (
    discrete_dynamics,
    discrete_jacobians,
    estimate_input,
    rollout,
    weighted_dynamics_hessian,
)

EPS = 1e-6


def _fd_jacobians(x, u, h, method):
    A = np.zeros(x.shape + (3,))
    B = np.zeros(x.shape[:-1] + (3, 2))
    for i in range(3):
        d = np.zeros(3)
        d[i] = EPS
        A[..., :, i] = (discrete_dynamics(x + d, u, h, method)
                        - discrete_dynamics(x - d, u, h, method)) / (2 * EPS)
    for i in range(2):
        d = np.zeros(2)
        d[i] = EPS
        B[..., :, i] = (discrete_dynamics(x, u + d, h, method)
                        - discrete_dynamics(x, u - d, h, method)) / (2 * EPS)
    return A, B


@pytest.mark.parametrize("method", ["euler", "rk4", "exact"])
def test_jacobians_match_finite_differences(method: str) -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=(4, 8, 3)) * [2.0, 2.0, 3.0]
    u = rng.normal(size=(4, 8, 2)) * 0.5
    nxt, A, B = discrete_jacobians(x, u, 0.5, method)
    A_fd, B_fd = _fd_jacobians(x, u, 0.5, method)
    np.testing.assert_allclose(nxt, discrete_dynamics(x, u, 0.5, method), atol=0, rtol=0)
    np.testing.assert_allclose(A, A_fd, atol=1e-8)
    np.testing.assert_allclose(B, B_fd, atol=1e-8)


@pytest.mark.parametrize("method", ["euler", "rk4", "exact"])
def test_weighted_hessian_matches_finite_differences(method: str) -> None:
    rng = np.random.default_rng(2)
    x = rng.normal(size=(3, 3))
    u = rng.normal(size=(3, 2))
    lam = rng.normal(size=(3, 3))
    H = weighted_dynamics_hessian(x, u, lam, 1.0, method)

    def grad(xx, uu):  # gradient of lam' f_d in (psi, v, omega)
        _, A, B = discrete_jacobians(xx, uu, 1.0, method)
        return np.concatenate((np.einsum("ni,ni->n", lam, A[..., :, 2])[:, None],
                               np.einsum("ni,nij->nj", lam, B)), axis=1)

    H_fd = np.zeros_like(H)
    for col in range(3):
        dx, du = np.zeros(3), np.zeros(2)
        if col == 0:
            dx[2] = EPS
        else:
            du[col - 1] = EPS
        H_fd[..., :, col] = (grad(x + dx, u + du) - grad(x - dx, u - du)) / (2 * EPS)
    np.testing.assert_allclose(H, H_fd, atol=2e-7)
    np.testing.assert_allclose(H, np.swapaxes(H, -1, -2), atol=1e-12)


def test_euler_is_paper_equation_3() -> None:
    x = np.array([1.0, -2.0, 0.3])
    u = np.array([0.4, -0.2])
    expected = x + 0.5 * np.array([0.4 * np.cos(0.3), 0.4 * np.sin(0.3), -0.2])
    np.testing.assert_allclose(discrete_dynamics(x, u, 0.5), expected, rtol=0, atol=1e-15)


def test_rk4_converges_to_exact_arc() -> None:
    # constant (v, omega): exact solution is a circular arc
    x0 = np.array([0.0, 0.0, 0.2])
    v, w, T = 0.6, 0.5, 2.0
    exact = np.array([v / w * (np.sin(0.2 + w * T) - np.sin(0.2)),
                      -v / w * (np.cos(0.2 + w * T) - np.cos(0.2)), 0.2 + w * T])
    err = {}
    for n in (10, 20):
        xs = rollout(x0, np.tile([v, w], (n, 1)), T / n, "rk4")
        err[n] = np.abs(xs[-1] - exact).max()
    assert err[20] < err[10] / 12  # fourth order: ratio ~16


def test_estimate_input_inverts_euler() -> None:
    x = np.array([[0.5, 1.0, -2.9], [0.0, 0.0, 3.1]])
    u = np.array([[0.3, 0.7], [-0.5, 0.4]])
    np.testing.assert_allclose(estimate_input(x, discrete_dynamics(x, u, 0.5), 0.5), u,
                               atol=1e-12)


def test_unknown_discretization_is_refused() -> None:
    with pytest.raises(ProblemError, match="discretization"):
        discrete_dynamics(np.zeros(3), np.zeros(2), 0.1, "midpoint")


@pytest.mark.parametrize("method", ["euler", "rk4", "exact"])
def test_rollout_equals_repeated_steps(method: str) -> None:
    rng = np.random.default_rng(5)
    x0 = rng.normal(size=(4, 3))
    u = rng.normal(size=(7, 4, 2))
    xs = rollout(x0, u, 0.3, method)
    step = [x0]
    for k in range(7):
        step.append(discrete_dynamics(step[-1], u[k], 0.3, method))
    np.testing.assert_allclose(xs, np.stack(step), atol=1e-12)


def test_exact_step_is_the_closed_form_arc() -> None:
    x0 = np.array([0.3, -1.0, 0.2])
    v, w, h = 0.6, 0.5, 2.0
    arc = np.array([0.3 + v / w * (np.sin(0.2 + w * h) - np.sin(0.2)),
                    -1.0 - v / w * (np.cos(0.2 + w * h) - np.cos(0.2)), 0.2 + w * h])
    np.testing.assert_allclose(discrete_dynamics(x0, np.array([v, w]), h, "exact"), arc,
                               rtol=0, atol=1e-15)
    # and RK4 with many steps converges to it
    fine = rollout(x0, np.tile([v, w], (400, 1)), h / 400, "rk4")[-1]
    np.testing.assert_allclose(fine, arc, atol=1e-12)


def test_exact_step_is_smooth_through_zero_turn_rate() -> None:
    x0 = np.array([0.0, 0.0, 0.7])
    h = 0.5
    # omega = 0: the straight segment (the Euler step)
    straight = discrete_dynamics(x0, np.array([0.4, 0.0]), h, "exact")
    np.testing.assert_allclose(straight, discrete_dynamics(x0, np.array([0.4, 0.0]), h),
                               atol=1e-16)
    # on both sides of the series switch (|a| = 1e-3) the step and the Jacobians are
    # continuous, and the Jacobians match finite differences right at omega = 0
    for w in (0.0, 2e-3 / h * (1 - 1e-9), 2e-3 / h * (1 + 1e-9), -1e-9, 1e-7):
        x = np.array([0.1, 0.2, 0.7])
        u = np.array([0.4, w])
        nxt, A, B = discrete_jacobians(x, u, h, "exact")
        A_fd, B_fd = _fd_jacobians(x, u, h, "exact")
        np.testing.assert_allclose(A, A_fd, atol=1e-9)
        np.testing.assert_allclose(B, B_fd, atol=1e-9)
    below = discrete_jacobians(x, np.array([0.4, 2e-3 / h * (1 - 1e-12)]), h, "exact")
    above = discrete_jacobians(x, np.array([0.4, 2e-3 / h * (1 + 1e-12)]), h, "exact")
    for lo, hi in zip(below, above, strict=True):
        np.testing.assert_allclose(lo, hi, atol=1e-14)
