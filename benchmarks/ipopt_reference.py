r"""Converged reference: the same OCP solved to convergence by CasADi + IPOPT each sample.

The NLP is the centralized OCP of paper eq. 7 with Euler (or RK4) dynamics,
input bounds, optional position bounds and the *nonlinear* distance
constraints of eq. 5 on stages 1..N, written as
:math:`\|p_j - p_l\|^2 \ge d_{jl}^2` (smooth), with IPOPT's exact Hessian.
There are no slacks, no safety margin and no detour rule: it is the plain
OCP, so in symmetric encounters the converged closed loop may stop in a
standoff (deadlock); the benchmark reports that through the final position
errors.

The solver function is built once per scenario (CasADi ``SX`` graph, so that
IPOPT's callbacks are cheap and the timing is fair to the reference); every
sample passes the measured state and the references as parameters and
warm-starts from the shifted previous primal solution and, by default, the
previous multipliers (``warm_start_init_point`` with ``mu_init = 1e-4``,
which halves IPOPT's iterations against a primal-only warm start). IPOPT's
controller time is the wall time of the whole :meth:`IpoptReference.step`
(reference sampling, shifted guess, solver call, first input), like sqpmpc's
``compute_time``. CasADi is a benchmark
extra (``pip install .[bench]``).
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from sqpmpc.models.unicycle import discrete_dynamics
from sqpmpc.problem.scenario import Scenario
from sqpmpc.sim.record import RunRecord

__all__ = ["WARM_MU_INIT", "IpoptReference", "IpoptSample", "simulate_ipopt"]

WARM_MU_INIT = 1e-4
"""Initial barrier parameter when the multipliers are warm-started."""


def _f_d(x: ca.SX, u: ca.SX, h: float, method: str) -> ca.SX:
    """Symbolic one-step unicycle model, same discretizations as :mod:`sqpmpc.models.unicycle`."""

    def f(xx: ca.SX) -> ca.SX:
        return ca.vertcat(u[0] * ca.cos(xx[2]), u[0] * ca.sin(xx[2]), u[1])

    if method == "euler":
        return x + h * f(x)
    if method != "rk4":
        raise ValueError(f"method must be 'euler' or 'rk4', got {method!r}")
    k1 = f(x)
    k2 = f(x + 0.5 * h * k1)
    k3 = f(x + 0.5 * h * k2)
    k4 = f(x + h * k3)
    return x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


@dataclass
class IpoptSample:
    """One reference sample.

    Attributes
    ----------
    inputs
        ``(n, 2)`` inputs to apply (within the input bounds).
    success
        IPOPT reported success (``Solve_Succeeded`` or ``Solved_To_Acceptable_Level``).
    wall_time
        Wall time of the whole step (controller time), s.
    iterations
        IPOPT iterations.
    status
        IPOPT's return status.
    """

    inputs: np.ndarray
    success: bool
    wall_time: float
    iterations: int
    status: str


class IpoptReference:
    r"""Centralized NMPC solved to convergence with IPOPT (exact Hessian).

    Parameters
    ----------
    scenario
        The problem.
    method
        Discretization, ``"euler"`` or ``"rk4"``.
    tol
        IPOPT's ``tol`` (and ``acceptable_tol``).
    max_iter
        IPOPT's iteration cap per sample.
    warm_start_duals
        Also pass the previous multipliers (``lam_g``, ``lam_x``) with IPOPT's
        ``warm_start_init_point = yes`` and ``mu_init = WARM_MU_INIT``; when
        false only the primal guess is warm-started (IPOPT's default start).
    ipopt_options
        Further IPOPT options (without the ``ipopt.`` prefix); they override
        the ones above.
    intersample_points
        ``m >= 1`` also requires the distance at ``m`` evenly spaced interior
        points of every interval, stage 0 to 1 included: with Euler dynamics
        a robot moves on the straight segment between its stage positions, so
        :math:`\|(1-s) r_i + s\,r_{i+1}\|^2 \ge d^2` at
        :math:`s = 1/(m+1), \dots, m/(m+1)` keeps robots from passing
        through each other between samples (eq. 5 alone only constrains the
        samples). ``0`` (default) is the plain eq. 5.
    """

    def __init__(self, scenario: Scenario, method: str = "euler", tol: float = 1e-8,
                 max_iter: int = 500, warm_start_duals: bool = True,
                 ipopt_options: dict[str, Any] | None = None,
                 intersample_points: int = 0) -> None:
        self.scenario = scenario
        self.method = method
        n, N, h = scenario.n_robots, scenario.horizon, scenario.sample_time
        self.n, self.N = n, N
        X = ca.SX.sym("X", 3 * n, N + 1)
        U = ca.SX.sym("U", 2 * n, N)
        x0 = ca.SX.sym("x0", 3 * n)
        ref = ca.SX.sym("ref", 2 * n, N)
        Q = np.asarray(scenario.weights.Q, dtype=float)
        R = np.asarray(scenario.weights.R, dtype=float)
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
                d_prev = X[3 * a:3 * a + 2, i - 1] - X[3 * b:3 * b + 2, i - 1]
                for s in np.arange(1, intersample_points + 1) / (intersample_points + 1):
                    d_s = (1.0 - s) * d_prev + s * d
                    g.append(ca.dot(d_s, d_s))
                    lbg.append(np.array([dreq[a, b] ** 2]))
                    ubg.append(np.array([np.inf]))
        self._lbg = np.concatenate(lbg)
        self._ubg = np.concatenate(ubg)
        w = ca.vertcat(ca.vec(X), ca.vec(U))
        self._nX = 3 * n * (N + 1)
        ulo, uup = scenario.bounds.input_lower(), scenario.bounds.input_upper()
        plo, pup = scenario.bounds.position_lower(), scenario.bounds.position_upper()
        xlo = np.tile(np.r_[np.maximum(plo, -np.inf), -np.inf], n * (N + 1))
        xup = np.tile(np.r_[np.minimum(pup, np.inf), np.inf], n * (N + 1))
        # the measured state is fixed by the equality rows; bounds apply to stages 1..N
        xlo[: 3 * n] = -np.inf
        xup[: 3 * n] = np.inf
        self._lbw = np.r_[xlo, np.tile(ulo, n * N)]
        self._ubw = np.r_[xup, np.tile(uup, n * N)]
        nlp = {"x": w, "p": ca.vertcat(x0, ca.vec(ref)), "f": cost, "g": ca.vertcat(*g)}
        opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.tol": tol,
                "ipopt.acceptable_tol": tol, "ipopt.max_iter": int(max_iter),
                "ipopt.hessian_approximation": "exact", "ipopt.sb": "yes"}
        if warm_start_duals:
            opts["ipopt.warm_start_init_point"] = "yes"
            opts["ipopt.mu_init"] = WARM_MU_INIT
        opts.update({f"ipopt.{key}": value for key, value in (ipopt_options or {}).items()})
        self.solver = ca.nlpsol("ocp", "ipopt", nlp, opts)
        self.warm_start_duals = warm_start_duals
        self._w: np.ndarray | None = None
        self._lam: tuple[np.ndarray, np.ndarray] | None = None

    def _split(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Decision vector to states ``(n, N+1, 3)`` and inputs ``(n, N, 2)``."""
        n, N = self.n, self.N
        X = w[: self._nX].reshape(N + 1, 3 * n).T.reshape(n, 3, N + 1)
        U = w[self._nX:].reshape(N, 2 * n).T.reshape(n, 2, N)
        return np.transpose(X, (0, 2, 1)), np.transpose(U, (0, 2, 1))

    def _join(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`_split`."""
        n, N = self.n, self.N
        Xc = np.transpose(X, (0, 2, 1)).reshape(3 * n, N + 1)
        Uc = np.transpose(U, (0, 2, 1)).reshape(2 * n, N)
        return np.r_[Xc.T.ravel(), Uc.T.ravel()]

    def _guess(self, states: np.ndarray) -> np.ndarray:
        """Shifted previous solution (last input held), or the resting rollout at first."""
        n, N, h = self.n, self.N, self.scenario.sample_time
        if self._w is None:
            U = np.zeros((n, N, 2))
            X = np.repeat(states[:, None], N + 1, axis=1)
        else:
            X, U = self._split(self._w)
            last = discrete_dynamics(X[:, -1], U[:, -1], h, self.method)
            X = np.concatenate((X[:, 1:], last[:, None]), axis=1)
            U = np.concatenate((U[:, 1:], U[:, -1:]), axis=1)
            X[:, 0] = states
        return self._join(X, U)

    def step(self, t: float, states: np.ndarray) -> IpoptSample:
        """Solve the OCP at time ``t`` from the measured ``states (n, 3)``.

        Parameters
        ----------
        t
            Sample time :math:`t_k`, s.
        states
            Measured states, ``(n, 3)``.

        Returns
        -------
        IpoptSample
            The first input of the solution (clipped to the bounds). When IPOPT
            fails with a non-finite iterate the first input of the shifted
            previous solution (or zero) is applied and the warm start is reset.
        """
        t0 = time.perf_counter()
        sc = self.scenario
        n, N, h = self.n, self.N, sc.sample_time
        states = np.asarray(states, dtype=float)
        times = t + h * np.arange(1, N + 1)
        ref = sc.reference_positions(times)  # (N, n, 2)
        p = np.r_[states.ravel(), np.transpose(ref, (1, 2, 0)).reshape(2 * n, N).T.ravel()]
        guess = self._guess(states)
        kwargs = {"x0": guess, "p": p, "lbx": self._lbw, "ubx": self._ubw,
                  "lbg": self._lbg, "ubg": self._ubg}
        if self.warm_start_duals and self._lam is not None:
            kwargs["lam_g0"], kwargs["lam_x0"] = self._lam
        sol = self.solver(**kwargs)
        stats = self.solver.stats()
        w = np.asarray(sol["x"], dtype=float).ravel()
        if np.all(np.isfinite(w)):
            self._w = w
            self._lam = (np.asarray(sol["lam_g"], dtype=float).ravel(),
                         np.asarray(sol["lam_x"], dtype=float).ravel())
        else:  # keep going from the shifted guess; counted as a failure
            self._w = self._lam = None
            w = guess
        _, U = self._split(w)
        u0 = np.clip(U[:, 0], sc.bounds.input_lower(), sc.bounds.input_upper())
        wall = time.perf_counter() - t0
        return IpoptSample(u0, bool(stats["success"]), wall, int(stats["iter_count"]),
                           str(stats["return_status"]))


def simulate_ipopt(scenario: Scenario, method: str = "euler",
                   **kwargs: Any) -> tuple[RunRecord, int]:
    """Closed loop with the IPOPT reference.

    Parameters
    ----------
    scenario
        The problem; the plant uses the same discretization as the OCP.
    method
        ``"euler"`` or ``"rk4"``.
    **kwargs
        Passed to :class:`IpoptReference` (``tol``, ``max_iter``,
        ``warm_start_duals``, ``ipopt_options``).

    Returns
    -------
    tuple[RunRecord, int]
        The record (scheme ``"ipopt-centralized"``; ``extra`` holds the IPOPT
        iteration total and the count of each return status) and the number
        of samples where IPOPT did not report success.
    """
    ref = IpoptReference(scenario, method, **kwargs)
    K, n = scenario.steps, scenario.n_robots
    states = np.zeros((K + 1, n, 3))
    states[0] = scenario.initial_states()
    inputs = np.zeros((K, n, 2))
    times = np.zeros((K, 1))
    failures = 0
    iterations = 0
    statuses: Counter[str] = Counter()
    t = scenario.sample_time * np.arange(K + 1)
    for k in range(K):
        s = ref.step(t[k], states[k])
        failures += not s.success
        iterations += s.iterations
        statuses[s.status] += 1
        inputs[k] = s.inputs
        times[k, 0] = s.wall_time
        states[k + 1] = discrete_dynamics(states[k], s.inputs, scenario.sample_time, method)
    extra = {"ipopt_iterations_total": iterations, "ipopt_statuses": dict(statuses),
             "discretization": method}
    record = RunRecord(scenario=scenario, scheme="ipopt-centralized", t=t, states=states,
                       inputs=inputs, solve_times=times, solver_failures=failures,
                       completed=True, extra=extra)
    return record, failures
