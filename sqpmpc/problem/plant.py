r"""The plant: how the simulated robots really move, and how far that is from a prediction.

A scenario's ``[plant]`` section (:class:`PlantSpec`) says which model moves the
robots (``"euler"``, the paper's eq. 3 and the default; ``"rk4"``; ``"exact"``,
the unicycle integrated exactly under a zero-order-hold input,
:mod:`sqpmpc.models.unicycle`) and the standard deviation of Gaussian noise added to the
applied :math:`(v, \omega)`. :class:`Plant` steps the robots with it.

Model mismatch made safe
------------------------
A controller predicts with its own discretization, the plant moves with its
model and a perturbed input. The safety checks of the first input
(:mod:`sqpmpc.ocp.collision_rows`) hold for the plant's *true path* over the sample
when that path stays within a known distance of the segment the controller
predicted. For a robot at :math:`p_0` with predicted next position
:math:`\hat p_1` and commanded input :math:`u = (v, \omega)`, the true position
at the fraction :math:`s \in [0, 1]` of the sample satisfies

.. math::

    \big\lVert p(s T_s) - \big((1 - s) p_0 + s \hat p_1\big) \big\rVert
    \le \alpha s + \beta s (1 - s),

with :math:`(\alpha, \beta)` from :func:`path_deviation`. The bounds come from
:math:`\lVert \dot p - v e^{i\psi_0} \rVert \le |v \omega| t` along an arc
(:math:`T_s`, the bounds and the noise only; :math:`V = |v| + W_v`,
:math:`W` the noise bound):

==================  ==================================================
prediction vs plant deviation of the path from the predicted segment
==================  ==================================================
same model          0: the plant moves on the predicted segment
exact vs exact      the arc from its chord: :math:`\beta = |v\omega| T_s^2/2`
euler vs exact      :math:`|v\omega| T_s^2 s^2/2`: :math:`\alpha = -\beta = |v\omega|T_s^2/2`
two chords          the end points' distance, linear in :math:`s`
input noise         :math:`\alpha \mathrel{+}= W_v T_s + V W_\omega T_s^2/2`
==================  ==================================================

(RK4 is Simpson's rule on :math:`\int e^{i\psi}`: its end point is within
:math:`\sqrt 2 |v| \omega^4 T_s^5 / 2880` of the exact one; an RK4 plant is taken
to move on its chord.) The noise is Gaussian truncated at
:data:`NOISE_TRUNCATION` standard deviations (an actuator never applies an
unbounded error; the truncated mass is :math:`6 \cdot 10^{-5}`), so
:math:`W = 4\sigma` is a hard bound.

The QP rows keep :func:`model_margin` more than the required distance: twice
the largest linear growth :math:`\alpha + \max(\beta, 0)` over the input bounds
(each robot of a pair may deviate by it; half as much against an obstacle).
For a plant that moves exactly as predicted (the default: Euler both) it is 0.

Robots with acceleration limits (CONTRACT 1c)
---------------------------------------------
With ``[bounds] acceleration`` and ``angular_acceleration`` the plant's state
includes the velocities :math:`(v, \omega)`; a command is followed by the
constant accelerations :math:`a = \mathrm{clip}((v_{cmd} - v)/T_s, a_{\min},
a_{\max})` (likewise :math:`\alpha`) over the sample, so the velocity changes
linearly and never faster than the limits, and reaches the command at the end of
the sample when the limits allow (the controller's commands always do). The
controller predicts with :class:`~sqpmpc.models.acceleration.AccelerationUnicycle`;
:func:`acceleration_path_deviation` bounds how far such a robot is from the
predicted segment :math:`p_0 \to \hat p_1` over the sample, with
:math:`V = \max(|v_0|, |v_1|)`, :math:`\Omega = \max(|\omega_0|, |\omega_1|)`
(the velocities at both ends) and :math:`\gamma = V\Omega T_s^2/2`:

- *along the path*: the segment is checked as travelled at a uniform rate, the
  robot covers :math:`v_0 sT_s + a s^2T_s^2/2` of it: the gap is
  :math:`|a| T_s^2 s(1-s)/2`, so :math:`\beta \mathrel{+}= |a|T_s^2/2`;
- *off the path* (a plant whose heading turns during the sample, ``rk4`` or
  ``exact``): :math:`|\psi(t) - \psi_0| \le \Omega t`, so the robot is within
  :math:`\int_0^t V\Omega\tau\,d\tau = \gamma s^2` of the straight line it would
  follow along :math:`\psi_0`: Euler prediction, :math:`\alpha \mathrel{+}= \gamma`,
  :math:`\beta \mathrel{-}= \gamma`; an arc predicted from its own end point
  (``rk4``/``exact`` prediction): :math:`\gamma(s^2 + s)`, :math:`\alpha \mathrel{+}=
  2\gamma`, :math:`\beta \mathrel{-}= \gamma`; an Euler plant under an ``rk4``/``exact``
  prediction: the end points are :math:`\gamma` apart, :math:`\alpha \mathrel{+}= \gamma`;
- *input noise* :math:`W` on the commanded velocities changes the accelerations by
  at most :math:`W/T_s`: :math:`\alpha \mathrel{+}= W_v T_s/2 + V W_\omega T_s^2/6`.

(RK4 integrates the heading and the velocities exactly here and the position to
:math:`O(T_s^5)`; it is taken to move as the exact solution.) The first-input and
braking checks of these robots take the bound :math:`\alpha s + \beta s(1-s)` itself
(:mod:`sqpmpc.kernels.acceleration`, and the half-planes as before). The centralized
rows and the rows against obstacles and missing neighbours keep, as for the paper's
robot, twice the largest linear growth :math:`\alpha + \max(\beta, 0)` over the
velocity and acceleration boxes: :math:`|a|_{\max}T_s^2` for the Euler plant, 0.25 m
on paper-s2 with ``acceleration = [-1, 1]`` (it covers a robot that starts on its
check line). The decentralized shared rows keep what the robot's current height
above its check line needs, at least twice the largest value of the bound
(:func:`largest_deviation`, a quarter of the above for the Euler plant):
:mod:`sqpmpc.problem.margins`. (That quarter kept by every row of both schemes,
measured on ``benchmarks/acceleration.py``, 24 runs, 0 collisions either way, made 22
instead of 19 runs arrive, but paper-s2 decentralized ended 0.116 m from its moving
reference, outside the paper robot's band of 0.095 m.)

Braking takes several samples: from :math:`v` it takes
:math:`\lceil |v|/(|a_{\min}|T_s)\rceil` samples and about :math:`v^2/(2|a_{\min}|)`
of travel (0.18 m from 0.6 m/s at 1 m/s^2). The controllers therefore accept a
first input only if braking right after it keeps every distance too
(:meth:`sqpmpc.control.pipeline.ControllerPipeline.braking_path` and the schemes'
braking checks), so the
braking fallback of the next sample follows a path already checked.

A plant that lags (the paper's robot on real wheels)
-----------------------------------------------------
The paper's robot changes its velocities at once, so standing still is always safe and
the brake fallback is never checked. A robot on wheels cannot: its speed holds for a
delay :math:`\tau` and then moves towards a new command at some acceleration
:math:`a` or faster, never beyond it (``[plant] response = [tau, a]``; the physics
plant derives both from its robot, :meth:`sqpmpc.sim.physics.PhysicalRobot.response`).
After a change :math:`\Delta` of the commanded speed its path is then ahead of or behind
the one the model predicts by at most

.. math::

    \int_0^t |v - v_{cmd}| \le \min\big(|\Delta| t,\; c(\Delta)\big),
    \qquad c(\Delta) = |\Delta|\tau + \frac{\Delta^2}{2a},

and :math:`\min(|\Delta| T_s s, c) \le c\,s + |\Delta| T_s\,s(1-s)` on :math:`[0, 1]`.
The checks take as :math:`\Delta` the change from the command of the sample before,
the speed a sample starts with when the speed settles within a sample
(:math:`\tau + (v_{\max} - v_{\min})/a \le T_s`, which the scenario checks). Off the
heading's line the robot strays as an exact plant does, its yaw rate anywhere between
the two commands: :math:`|\psi(t) - \psi_0| \le \Omega t`,
:math:`\Omega = \max(|\omega|, |\omega_{prev}|)`, so
:math:`|v|\Omega T_s^2 s^2/2` from the Euler segment (and the turn :math:`|v\omega|
T_s^2/2` more, linearly, from an ``exact`` or ``rk4`` prediction's chord). A brake
command at the next sample (the fallback, unchecked) then takes the robot at most
:math:`c(|v|)` from where the sample left it: the bound adds that coast to
:math:`\alpha`, so an accepted input leaves room to brake, and the induction of the
safety argument holds again. In all (:func:`path_deviation` with ``response``):

.. math::

    \alpha = |v|\Omega T_s^2/2 + c(\Delta) + c(|v|) \;(+\ \text{noise, prediction}),
    \qquad \beta = |\Delta| T_s - |v|\Omega T_s^2/2 .

The rows keep :func:`model_margin`, here the bend's and the full-speed coast's
:math:`2(v_{\max}\omega_{\max}T_s^2/2 + c(v_{\max}))` (0.238 m for the nominal
physical robot at the paper's bounds), not the lag of a change of command, which only
two commands define; the centralized check takes the bound itself rather than its linear
majorant (the lag grows at the rate of the change near :math:`s = 0` and is a fraction of
that by :math:`s = 1`; :func:`sqpmpc.kernels.pair_paths.pairs_keep_ramp_distance` with no
ramp), and a first input the check refuses for its change is tried again at a half and
a quarter of that change before the fallbacks
(:meth:`sqpmpc.control.pipeline.ControllerPipeline.verify`, counter ``eased_inputs``).
:class:`Plant` moves such a robot with the slowest response the spec allows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.models.acceleration import acceleration_dynamics
from sqpmpc.models.unicycle import DISCRETIZATIONS, discrete_dynamics

__all__ = [
    "NOISE_TRUNCATION",
    "acceleration_path_deviation",
    "corner_deviations",
    "ramp_accelerations",
    "largest_deviation",
    "PLANT_MODELS",
    "Plant",
    "PlantSpec",
    "linear_growth",
    "model_margin",
    "path_deviation",
]

#: The plant models a scenario's ``[plant] model`` accepts.
PLANT_MODELS: tuple[str, ...] = DISCRETIZATIONS
#: Input noise is Gaussian truncated at this many standard deviations.
NOISE_TRUNCATION = 4.0


@dataclass(frozen=True)
class PlantSpec:
    """The scenario's ``[plant]`` section.

    Parameters
    ----------
    model
        ``"euler"`` (default), ``"rk4"`` or ``"exact"``.
    input_noise
        Standard deviations :math:`(\\sigma_v, \\sigma_\\omega) \\ge 0` of the noise
        added to the applied input.
    seed
        Seed of the noise (an integer >= 0).
    response
        ``(delay, acceleration)``, or ``None`` (default): the paper's robot, whose
        velocities change at once. With it the plant's speed follows a change of the
        commanded speed late, never beyond the command: it holds for at most ``delay`` s
        (>= 0), then moves towards the command at ``acceleration`` m/s^2 (> 0) or faster
        (module notes, "A plant that lags"). Only with ``model = "exact"`` (a plant that
        lags moves continuously) and for robots without acceleration bounds.
    """

    model: str = "euler"
    input_noise: tuple[float, float] = (0.0, 0.0)
    seed: int = 0
    response: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.model not in PLANT_MODELS:
            raise ProblemError(f"model: expected one of {', '.join(map(repr, PLANT_MODELS))}, "
                               f"found {self.model!r}")
        noise = self.input_noise
        if (not isinstance(noise, list | tuple | np.ndarray) or len(noise) != 2
                or any(isinstance(x, bool) or not isinstance(x, int | float | np.floating)
                       or not math.isfinite(x) or x < 0 for x in noise)):
            raise ProblemError("input_noise: expected an array of 2 finite numbers >= 0 "
                               f"[sigma_v, sigma_omega], found {noise!r}")
        object.__setattr__(self, "input_noise", (float(noise[0]), float(noise[1])))
        if (isinstance(self.seed, bool) or not isinstance(self.seed, int | np.integer)
                or not 0 <= self.seed < 2**63):
            raise ProblemError(f"seed: expected an integer in [0, 2^63), found {self.seed!r}")
        object.__setattr__(self, "seed", int(self.seed))
        if self.response is not None:
            r = self.response
            if (not isinstance(r, list | tuple | np.ndarray) or len(r) != 2
                    or any(isinstance(x, bool) or not isinstance(x, int | float | np.floating)
                           or not math.isfinite(x) for x in r) or r[0] < 0 or r[1] <= 0):
                raise ProblemError("response: expected an array of 2 finite numbers [delay >= 0 "
                                   f"(s), acceleration > 0 (m/s^2)], found {r!r}")
            if self.model != "exact":
                raise ProblemError(f"response: a plant that lags moves continuously: declare "
                                   f"model = \"exact\" with it (found {self.model!r})")
            object.__setattr__(self, "response", (float(r[0]), float(r[1])))

    def speed_lag(self, change: np.ndarray | float) -> np.ndarray:
        r""":math:`c(\Delta) = |\Delta| \tau + \Delta^2 / (2a)`: the most the plant's path can
        run ahead of or lag behind that of a speed that changes at once by ``change``
        (:math:`\Delta`, m/s), m (``response`` :math:`(\tau, a)`; 0 without it)."""
        d = np.abs(np.asarray(change, dtype=float))
        if self.response is None:
            return np.zeros_like(d)
        delay, accel = self.response
        return d * delay + d * d / (2.0 * accel)

    def settling_time(self, change: float) -> float:
        """The longest the plant's speed takes to reach a command ``change`` m/s away, s
        (``delay + |change| / acceleration``; 0 without ``response``)."""
        if self.response is None:
            return 0.0
        return self.response[0] + abs(float(change)) / self.response[1]

    @property
    def noisy(self) -> bool:
        """Whether any input noise is added."""
        return self.input_noise != (0.0, 0.0)

    @property
    def noise_bound(self) -> np.ndarray:
        """The hard bound :math:`W = 4\\sigma` of the truncated noise, ``(2,)``."""
        return NOISE_TRUNCATION * np.asarray(self.input_noise)

    def to_dict(self) -> dict[str, object]:
        """The ``[plant]`` table (``response`` only when declared)."""
        out: dict[str, object] = {"model": self.model, "input_noise": list(self.input_noise),
                                  "seed": self.seed}
        if self.response is not None:
            out["response"] = list(self.response)
        return out


class Plant:
    """Steps the true robots: the spec's model with the (truncated Gaussian) input noise.

    Parameters
    ----------
    spec
        Model and noise.
    sample_time
        :math:`T_s`, s.
    n_robots
        Robots stepped together (the noise stream draws ``(n, 2)`` per step, so a
        run with the same seed and robots is reproducible).
    acceleration_bounds
        ``(lower (2,), upper (2,))`` of :math:`(a, \alpha)` (the scenario's
        ``[bounds] acceleration, angular_acceleration``), or ``None``: the paper's
        robot, whose velocities change at once. With them the plant keeps the
        robots' velocities (:attr:`velocities`, zero at the start) and changes them
        within the bounds (module notes).
    """

    def __init__(self, spec: PlantSpec, sample_time: float, n_robots: int,
                 acceleration_bounds: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self.spec = spec
        self.sample_time = float(sample_time)
        self.n_robots = int(n_robots)
        self._rng = np.random.default_rng(spec.seed)
        self._sigma = np.asarray(spec.input_noise)
        self.acceleration_bounds = None if acceleration_bounds is None else (
            np.asarray(acceleration_bounds[0], dtype=float),
            np.asarray(acceleration_bounds[1], dtype=float))
        #: ``(n, 2)`` the robots' velocities ``(v, omega)`` (with acceleration bounds)
        self.velocities = np.zeros((self.n_robots, 2))
        if spec.response is not None and self.acceleration_bounds is not None:
            raise ProblemError("[plant] response: for the paper's robot only; robots with "
                               "acceleration bounds ramp their velocities (CONTRACT 1c)")
        #: ``(n,)`` the speeds of a plant that lags (``spec.response``), zero at the start
        self.speeds = np.zeros(self.n_robots)

    @property
    def has_velocities(self) -> bool:
        """Whether the robots' velocities are states (acceleration bounds declared)."""
        return self.acceleration_bounds is not None

    def measure(self, states: np.ndarray) -> np.ndarray:
        """What the robots measure: poses ``(n, 3)``, with velocities ``(n, 5)``."""
        if not self.has_velocities:
            return states
        return np.concatenate((states, self.velocities), axis=1)

    def applied_inputs(self, inputs: np.ndarray) -> np.ndarray:
        """The inputs the robots really apply: ``inputs (n, 2)`` plus the noise."""
        inputs = np.asarray(inputs, dtype=float)
        if not self.spec.noisy:
            return inputs.copy()
        noise = self._rng.standard_normal(inputs.shape)
        np.clip(noise, -NOISE_TRUNCATION, NOISE_TRUNCATION, out=noise)
        return inputs + noise * self._sigma

    def step(self, states: np.ndarray, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Advance every robot by one sample :math:`T_s` with the commanded inputs held.

        Parameters
        ----------
        states
            ``(n, 3)`` states :math:`(x, y, \\psi)` at :math:`t_k`, in the scenario's
            robot order.
        inputs
            ``(n, 2)`` commanded inputs :math:`(v, \\omega)`, held on
            :math:`[t_k, t_{k+1})`.

        Returns
        -------
        next_states : np.ndarray
            ``(n, 3)`` states at :math:`t_{k+1}`, from the spec's model (``euler``,
            ``rk4`` or ``exact``) with the applied inputs.
        applied : np.ndarray
            ``(n, 2)`` inputs the robots really applied: ``inputs`` plus the truncated
            Gaussian input noise of the ``[plant]`` table (a copy of ``inputs``
            without noise); with acceleration bounds (CONTRACT 1c) the velocities the
            robots reach at the end of the sample (the commands when the bounds allow
            them). Give it to :meth:`sqpmpc.RunRecorder.append` as
            ``plant_inputs`` so the metrics see the true paths.

        Examples
        --------
        >>> x, applied = plant.step(x, out.inputs)  # doctest: +SKIP
        """
        applied = self.applied_inputs(inputs)
        if self.spec.response is not None:
            return self._lagging_step(np.asarray(states, dtype=float), applied), applied
        if not self.has_velocities:
            return discrete_dynamics(states, applied, self.sample_time, self.spec.model), applied
        lower, upper = self.acceleration_bounds
        h = self.sample_time
        accel = ramp_accelerations(applied, self.velocities, h, lower, upper)
        full = np.concatenate((np.asarray(states, dtype=float)[:, :3], self.velocities), axis=1)
        nxt = acceleration_dynamics(full, accel, h, self.spec.model)
        self.velocities = nxt[:, 3:5].copy()
        return nxt[:, :3], self.velocities.copy()


    def _lagging_step(self, states: np.ndarray, applied: np.ndarray) -> np.ndarray:
        """One sample of a plant that lags (``spec.response``): the speed held for the delay,
        then moved towards the command at the acceleration (the slowest response the spec
        allows), the yaw rate at once; exact arcs over :data:`LAG_SUBSTEPS` pieces, each
        at its mean speed."""
        delay, accel = self.spec.response
        h, pieces = self.sample_time, LAG_SUBSTEPS
        v0, target = self.speeds, applied[:, 0]
        ramp = np.abs(target - v0) / accel          # how long the speed moves
        direction = np.sign(target - v0)

        def travelled(t: float) -> np.ndarray:     # the distance covered by time t
            moving = np.clip(t - delay, 0.0, ramp)
            after = np.maximum(t - delay - ramp, 0.0)
            return v0 * np.minimum(t, delay) + v0 * moving + direction * accel * moving**2 / 2 \
                + target * after

        x = states[:, :3].copy()
        dt = h / pieces
        before = travelled(0.0)
        for j in range(1, pieces + 1):
            now = travelled(j * dt)
            x = discrete_dynamics(x, np.stack(((now - before) / dt, applied[:, 1]), axis=1),
                                  dt, "exact")
            before = now
        self.speeds = np.where(h >= delay + ramp, target,
                               v0 + direction * accel * np.clip(h - delay, 0.0, ramp))
        return x


#: Pieces of a sample :class:`Plant` integrates a plant that lags over (exact arcs, each at
#: the piece's mean speed: off the true integral by under 0.01 mm per sample at the paper's
#: bounds and 4 m/s^2).
LAG_SUBSTEPS = 50


def ramp_accelerations(target: np.ndarray, start: np.ndarray, duration: float,
                       lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    r"""The constant accelerations that take velocities ``start`` to ``target`` in
    ``duration`` s within the bounds: :math:`\mathrm{clip}((v_{cmd} - v)/T, a_{\min},
    a_{\max})` (CONTRACT 1c; :class:`Plant`, the physics plant's driver and the ROS 2
    robots ramp so), same shape as ``target``."""
    return np.clip((np.asarray(target, dtype=float) - start) / duration, lower, upper)


def _simpson_error(speed: np.ndarray, rate: np.ndarray, h: float) -> np.ndarray:
    """Bound on the distance between the RK4 and the exact end points."""
    return math.sqrt(2.0) * speed * rate**4 * h**5 / 2880.0


def path_deviation(inputs: np.ndarray, sample_time: float, prediction: str, plant: str,
                   noise_bound: np.ndarray | None = None,
                   response: PlantSpec | None = None,
                   previous: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    r"""Coefficients :math:`(\alpha, \beta)` of the path-deviation bound (module notes).

    Parameters
    ----------
    inputs
        Commanded inputs ``(..., 2)``.
    sample_time
        :math:`T_s`.
    prediction, plant
        The controller's discretization and the plant model.
    noise_bound
        :math:`(W_v, W_\omega)`, the hard bound of the input noise (default none).
    response
        The ``[plant]`` spec when it declares a ``response`` (a plant that lags, module
        notes): the bound then also covers the lag after the change from ``previous``
        and the coast of the brake that may follow the sample; ``None`` otherwise.
    previous
        The commands ``(..., 2)`` of the sample before (the plant's velocities when this
        one starts; with ``response`` only, default ``inputs``: no change).

    Returns
    -------
    tuple of np.ndarray
        :math:`\alpha` and :math:`\beta`, shape ``inputs.shape[:-1]``;
        :math:`\alpha s + \beta s(1-s) \ge 0` on :math:`[0, 1]`.
    """
    for name, value in (("prediction", prediction), ("plant", plant)):
        if value not in DISCRETIZATIONS:
            raise ProblemError(f"{name} model must be one of {DISCRETIZATIONS}, got {value!r}")
    u = np.asarray(inputs, dtype=float)
    h = float(sample_time)
    v, w = np.abs(u[..., 0]), np.abs(u[..., 1])
    W = np.zeros(2) if noise_bound is None else np.asarray(noise_bound, dtype=float)
    if response is not None and response.response is not None:
        return _lagging_deviation(u, h, prediction, response, W,
                                  u if previous is None else np.asarray(previous, dtype=float))
    speed = v + W[0]
    turn = v * w * h * h / 2.0  # |v w| Ts^2 / 2: Euler vs exact end point, or arc vs chord
    zero = np.zeros_like(v)
    alpha, beta = zero.copy(), zero.copy()
    if plant == "exact":
        if prediction == "exact":
            beta = beta + turn
        elif prediction == "euler":
            alpha, beta = alpha + turn, beta - turn
        else:  # rk4: the exact arc from its chord, the chord from the RK4 end point
            alpha = alpha + _simpson_error(v, w, h)
            beta = beta + turn
    elif plant != prediction:  # the plant moves on a chord; the two end points differ
        # each end point against the exact one: Euler's is `turn` away, RK4's Simpson's error
        to_exact = {"euler": turn, "rk4": _simpson_error(v, w, h), "exact": zero}
        alpha = alpha + to_exact[plant] + to_exact[prediction]
    if W.any():
        noise_alpha = W[0] * h + speed * W[1] * h * h / 2.0
        if plant == "exact":  # the heading error grows along the sample: s^2
            alpha = alpha + noise_alpha
            beta = beta - speed * W[1] * h * h / 2.0
        else:  # a chord: the end point moves by at most noise_alpha (+ RK4's error twice)
            alpha = alpha + noise_alpha + 2.0 * _simpson_error(speed, w + W[1], h) * (
                plant == "rk4")
    return alpha, beta


def _lagging_deviation(u: np.ndarray, h: float, prediction: str, spec: PlantSpec,
                       W: np.ndarray, previous: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r""":func:`path_deviation` of a plant that lags (``spec.response``; module notes, "A plant
    that lags"): :math:`(\alpha, \beta)` of the bend, the noise, the lag after the change
    from ``previous``, the coast of a brake after the sample and the prediction's end point."""
    v, w = np.abs(u[..., 0]), np.abs(u[..., 1])
    speed = v + W[0]
    rate = np.maximum(w, np.abs(previous[..., 1])) + W[1]  # the yaw rate within the sample
    bend = speed * rate * h * h / 2.0      # |psi(t) - psi_0| <= rate t: off the heading's line
    change = np.abs(u[..., 0] - previous[..., 0]) + 2.0 * W[0]
    lag = spec.speed_lag(change)           # <= min(change t, lag): lag s + change Ts s (1 - s)
    coast = spec.speed_lag(speed)          # the brake that may follow: at most this far
    alpha = bend + W[0] * h + lag + coast
    beta = change * h - bend
    if prediction != "euler":  # the predicted end point is off the Euler one by the turn
        alpha = alpha + v * w * h * h / 2.0
        if prediction == "rk4":
            alpha = alpha + _simpson_error(v, w, h)
    return alpha, beta


def linear_growth(alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
    r"""The smallest :math:`G` with :math:`\alpha s + \beta s(1-s) \le G s` on :math:`[0, 1]`."""
    return alpha + np.maximum(beta, 0.0)


def largest_deviation(alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
    r"""The largest :math:`\alpha s + \beta s(1-s)` on :math:`[0, 1]` (:math:`\alpha \ge 0`):
    at :math:`s^* = \min(1, (\alpha + \beta)/(2\beta))` for :math:`\beta > 0`, else
    :math:`\alpha` (at :math:`s = 1`)."""
    alpha = np.asarray(alpha, dtype=float)
    beta = np.asarray(beta, dtype=float)
    safe = np.where(beta > 0.0, beta, 1.0)
    s = np.clip((alpha + beta) / (2.0 * safe), 0.0, 1.0)
    return np.where(beta > 0.0, alpha * s + beta * s * (1.0 - s), alpha)


def model_margin(input_lower: np.ndarray, input_upper: np.ndarray, sample_time: float,
                 prediction: str, plant: PlantSpec,
                 acceleration_bounds: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    r"""Margin the QP rows keep for a plant that differs from the prediction, m.

    Twice the largest :func:`linear_growth` over the input box (its corners:
    the bound grows with :math:`|v|` and :math:`|\omega|`); 0 when the plant
    moves exactly as predicted. E.g. Euler controller on an exact plant, or
    exact on exact: :math:`v_{\max}\omega_{\max}T_s^2` (0.118 m for the paper's
    bounds at :math:`T_s` = 0.5 s). A plant that lags (``plant.response``) adds the
    coast of a brake from full speed, :math:`c(v_{\max})` per robot, but not the lag of a
    change of command (two commands' property: the checks take it). With
    ``acceleration_bounds`` (robots with velocity states) the largest growth of
    :func:`acceleration_path_deviation` over the velocity and acceleration boxes (the
    checks of these robots take the bound itself, :func:`largest_deviation`; the rows keep
    the linear majorant, module notes).
    """
    lo, hi = np.asarray(input_lower, dtype=float), np.asarray(input_upper, dtype=float)
    if acceleration_bounds is not None:
        alpha, beta = corner_deviations(lo, hi, sample_time, prediction, plant,
                                        acceleration_bounds)
        return float(2.0 * linear_growth(alpha, beta).max())
    corners = np.array([[a, b] for a in (lo[0], hi[0]) for b in (lo[1], hi[1])])
    alpha, beta = path_deviation(corners, sample_time, prediction, plant.model,
                                 plant.noise_bound, plant if plant.response else None)
    return float(2.0 * linear_growth(alpha, beta).max())


def corner_deviations(input_lower: np.ndarray, input_upper: np.ndarray, sample_time: float,
                      prediction: str, plant: PlantSpec,
                      acceleration_bounds: tuple[np.ndarray, np.ndarray]
                      ) -> tuple[np.ndarray, np.ndarray]:
    r""":math:`(\alpha, \beta)` of :func:`acceleration_path_deviation`, ``(16,)`` each, at
    every corner of the velocity box paired with every corner of the acceleration box
    (the bound grows with each magnitude, so its largest values lie at the corners)."""
    lo, hi = np.asarray(input_lower, dtype=float), np.asarray(input_upper, dtype=float)
    alo, ahi = (np.asarray(b, dtype=float) for b in acceleration_bounds)
    vel = np.array([[a, b] for a in (lo[0], hi[0]) for b in (lo[1], hi[1])])
    acc = np.array([[a, b] for a in (alo[0], ahi[0]) for b in (alo[1], ahi[1])])
    return acceleration_path_deviation(
        np.repeat(vel, 4, axis=0), np.tile(acc, (4, 1)), sample_time, prediction,
        plant.model, plant.noise_bound, (lo, hi))


def acceleration_path_deviation(velocities: np.ndarray, accelerations: np.ndarray,
                                sample_time: float, prediction: str, plant: str,
                                noise_bound: np.ndarray | None = None,
                                velocity_bounds: tuple[np.ndarray, np.ndarray] | None = None,
                                ) -> tuple[np.ndarray, np.ndarray]:
    r"""Coefficients :math:`(\alpha, \beta)` of the path-deviation bound for a robot with
    velocity states (module notes, "Robots with acceleration limits").

    Parameters
    ----------
    velocities
        Velocities ``(..., 2)`` :math:`(v_0, \omega_0)` at the start of the sample.
    accelerations
        The sample's accelerations ``(..., 2)`` :math:`(a, \alpha)`.
    sample_time, prediction, plant, noise_bound
        As for :func:`path_deviation`.
    velocity_bounds
        ``(lower, upper)`` of :math:`(v, \omega)`: the end velocities are clipped to
        them (:func:`model_margin` evaluates the corners of both boxes).
    """
    for name, value in (("prediction", prediction), ("plant", plant)):
        if value not in DISCRETIZATIONS:
            raise ProblemError(f"{name} model must be one of {DISCRETIZATIONS}, got {value!r}")
    vel = np.asarray(velocities, dtype=float)
    acc = np.asarray(accelerations, dtype=float)
    h = float(sample_time)
    end = vel + h * acc
    if velocity_bounds is not None:
        end = np.clip(end, velocity_bounds[0], velocity_bounds[1])
    speed = np.maximum(np.abs(vel[..., 0]), np.abs(end[..., 0]))
    rate = np.maximum(np.abs(vel[..., 1]), np.abs(end[..., 1]))
    W = np.zeros(2) if noise_bound is None else np.asarray(noise_bound, dtype=float)
    speed = speed + W[0]
    rate = rate + W[1]
    gamma = speed * rate * h * h / 2.0
    alpha = np.zeros_like(speed)
    beta = np.abs(acc[..., 0]) * h * h / 2.0
    curved_plant = plant != "euler"
    curved_prediction = prediction != "euler"
    if curved_plant and not curved_prediction:
        alpha, beta = alpha + gamma, beta - gamma
    elif curved_plant:
        alpha, beta = alpha + 2.0 * gamma, beta - gamma
    elif curved_prediction:
        alpha = alpha + gamma
    if W.any():
        alpha = alpha + W[0] * h / 2.0 + speed * W[1] * h * h / 6.0
    return alpha, beta
