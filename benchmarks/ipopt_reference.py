r"""Converged reference: the same OCP solved to convergence by CasADi + IPOPT each sample.

The NLP is the centralized OCP of paper eq. 7 with Euler (or RK4) dynamics,
input bounds, optional position bounds and the *nonlinear* distance
constraints of eq. 5 on stages 1..N, written as
:math:`\|p_j - p_l\|^2 \ge d_{jl}^2` (smooth), with IPOPT's exact Hessian.
The solver function is built once per scenario; every sample passes the
measured state and the references as parameters and warm-starts from the
shifted previous solution. CasADi is a benchmark extra (``pip install .[bench]``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from sqpmpc.metrics import RunRecord
from sqpmpc.model import discrete_dynamics
from sqpmpc.scenario import Scenario

__all__ = ["IpoptReference", "simulate_ipopt"]


def _f_d(x: ca.MX, u: ca.MX, h: float, method: str) -> ca.MX:
    def f(xx: ca.MX) -> ca.MX:
        return ca.vertcat(u[0] * ca.cos(xx[2]), u[0] * ca.sin(xx[2]), u[1])

    if method == "euler":
        return x + h * f(x)
    k1 = f(x)
    k2 = f(x + 0.5 * h * k1)
    k3 = f(x + 0.5 * h * k2)
    k4 = f(x + h * k3)
    return x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


@dataclass
class IpoptSample:
    """One reference sample: inputs to apply, success, wall time and iterations."""

    inputs: np.ndarray
    success: bool
    wall_time: float
    iterations: int
    status: str


class IpoptReference:
    """Centralized NMPC solved to convergence with IPOPT (exact Hessian).

    Parameters
    ----------
    scenario
        The problem.
    method
        Discretization, ``"euler"`` or ``"rk4"``.
    tol
        IPOPT's ``tol``.
    """

    def __init__(self, scenario: Scenario, method: str = "euler", tol: float = 1e-8) -> None:
        self.scenario = scenario
        self.method = method
        n, N, h = scenario.n_robots, scenario.horizon, scenario.sample_time
        self.n, self.N = n, N
        X = ca.MX.sym("X", 3 * n, N + 1)
        U = ca.MX.sym("U", 2 * n, N)
        x0 = ca.MX.sym("x0", 3 * n)
        ref = ca.MX.sym("ref", 2 * n, N)
        Q = np.asarray(scenario.weights.Q)
        R = np.asarray(scenario.weights.R)
        cost = 0
        g, lbg, ubg = [X[:, 0] - x0], [np.zeros(3 * n)], [np.zeros(3 * n)]
        for i in range(N):
            for r in range(n):
                xr = X[3 * r:3 * r + 3, i]
                ur = U[2 * r:2 * r + 2, i]
                g.append(X[3 * r:3 * r + 3, i + 1] - _f_d(xr, ur, h, method))
                lbg.append(np.zeros(3))
                ubg.append(np.zeros(3))
                e = ref[2 * r:2 * r + 2, i] - X[3 * r:3 * r + 2, i + 1]
                cost += Q[0] * e[0] ** 2 + Q[1] * e[1] ** 2 + R[0] * ur[0] ** 2 + R[1] * ur[1] ** 2
        dreq = scenario.required_distances()
        for a, b in scenario.pairs():
            for i in range(1, N + 1):
                d = X[3 * a:3 * a + 2, i] - X[3 * b:3 * b + 2, i]
                g.append(ca.dot(d, d))
                lbg.append(np.array([dreq[a, b] ** 2]))
                ubg.append(np.array([np.inf]))
        self._lbg = np.concatenate(lbg)
        self._ubg = np.concatenate(ubg)
        w = ca.vertcat(ca.vec(X), ca.vec(U))
        self._nX = 3 * n * (N + 1)
        ulo, uup = scenario.bounds.input_lower(), scenario.bounds.input_upper()
        plo, pup = scenario.bounds.position_lower(), scenario.bounds.position_upper()
        xlo = np.tile(np.r_[np.maximum(plo, -1e20), -1e20], n * (N + 1))
        xup = np.tile(np.r_[np.minimum(pup, 1e20), 1e20], n * (N + 1))
        self._lbw = np.r_[xlo, np.tile(ulo, n * N)]
        self._ubw = np.r_[xup, np.tile(uup, n * N)]
        nlp = {"x": w, "p": ca.vertcat(x0, ca.vec(ref)), "f": cost, "g": ca.vertcat(*g)}
        opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.tol": tol,
                "ipopt.acceptable_tol": tol, "ipopt.max_iter": 500,
                "ipopt.hessian_approximation": "exact", "ipopt.sb": "yes"}
        self.solver = ca.nlpsol("ocp", "ipopt", nlp, opts)
        self._w: np.ndarray | None = None
        self._lam: np.ndarray | None = None

    def _split(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n, N = self.n, self.N
        X = w[: self._nX].reshape(N + 1, 3 * n).T.reshape(n, 3, N + 1)
        U = w[self._nX:].reshape(N, 2 * n).T.reshape(n, 2, N)
        return np.transpose(X, (0, 2, 1)), np.transpose(U, (0, 2, 1))

    def _join(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        n, N = self.n, self.N
        Xc = np.transpose(X, (0, 2, 1)).reshape(3 * n, N + 1)
        Uc = np.transpose(U, (0, 2, 1)).reshape(2 * n, N)
        return np.r_[Xc.T.ravel(), Uc.T.ravel()]

    def step(self, t: float, states: np.ndarray) -> IpoptSample:
        """Solve the OCP at time ``t`` from ``states (n, 3)``."""
        sc = self.scenario
        n, N, h = self.n, self.N, sc.sample_time
        times = t + h * np.arange(1, N + 1)
        ref = sc.reference_positions(times)  # (N, n, 2)
        p = np.r_[states.ravel(), np.transpose(ref, (1, 2, 0)).reshape(2 * n, N).T.ravel()]
        if self._w is None:
            U = np.zeros((n, N, 2))
            X = np.repeat(states[:, None], N + 1, axis=1)
        else:
            X, U = self._split(self._w)
            last = discrete_dynamics(X[:, -1], U[:, -1], h, self.method)
            X = np.concatenate((X[:, 1:], last[:, None]), axis=1)
            U = np.concatenate((U[:, 1:], U[:, -1:]), axis=1)
            X[:, 0] = states
        t0 = time.perf_counter()
        kwargs = {"x0": self._join(X, U), "p": p, "lbx": self._lbw, "ubx": self._ubw,
                  "lbg": self._lbg, "ubg": self._ubg}
        if self._lam is not None:
            kwargs["lam_g0"] = self._lam
        sol = self.solver(**kwargs)
        wall = time.perf_counter() - t0
        stats = self.solver.stats()
        self._w = np.asarray(sol["x"]).ravel()
        self._lam = np.asarray(sol["lam_g"]).ravel()
        _, U = self._split(self._w)
        u0 = np.clip(U[:, 0], sc.bounds.input_lower(), sc.bounds.input_upper())
        return IpoptSample(u0, bool(stats["success"]), wall, int(stats["iter_count"]),
                           str(stats["return_status"]))


def simulate_ipopt(scenario: Scenario, method: str = "euler") -> tuple[RunRecord, int]:
    """Closed loop with the IPOPT reference; returns the record and the failure count."""
    ref = IpoptReference(scenario, method)
    K, n = scenario.steps, scenario.n_robots
    states = np.zeros((K + 1, n, 3))
    states[0] = scenario.initial_states()
    inputs = np.zeros((K, n, 2))
    times = np.zeros((K, 1))
    failures = 0
    t = scenario.sample_time * np.arange(K + 1)
    for k in range(K):
        s = ref.step(t[k], states[k])
        failures += not s.success
        inputs[k] = s.inputs
        times[k, 0] = s.wall_time
        states[k + 1] = discrete_dynamics(states[k], s.inputs, scenario.sample_time, method)
    record = RunRecord(scenario=scenario, scheme="ipopt-centralized", t=t, states=states,
                       inputs=inputs, solve_times=times, solver_failures=failures,
                       completed=True, extra={})
    return record, failures
