r"""How much room the decentralized shared rows of robots with acceleration limits keep.

A robot with velocity states (``[bounds] acceleration``) can be up to
:math:`\alpha s + \beta s(1-s)` from the segment its controller predicted over a
sample (:func:`sqpmpc.problem.plant.acceleration_path_deviation`, with
:math:`\beta^+ = \max(\beta, 0)`). The rows used to keep the linear majorant
:math:`\alpha + \beta^+` beyond the line each robot's first-input check holds it to,
at every stage, whatever the robot's position: 0.25 m per robot at
:math:`|a| \le 2` m/s^2 and :math:`T_s = 0.5` s, 0.5 m between two robots, more
than the 0.8 m between two of corridor's goals leaves once keep-right tilts the
hyperplane. The margin a row needs depends on where the robot stands.

Where the robot stands decides the margin
-----------------------------------------
Let :math:`h_0 \ge 0` be the robot's current height above its check line and
:math:`h_1` that of its next predicted position; the predicted segment is at
height :math:`(1-s)h_0 + s h_1`, the true path at least that minus the deviation.
The check holds iff :math:`(1-s)h_0 + s h_1 \ge \alpha s + \beta^+ s(1-s)` on
:math:`(0, 1]`, i.e. :math:`h_1 \ge \alpha + \max_s (1-s)(\beta^+ - h_0/s)`. For
:math:`h_0 \ge \beta^+` the maximum is 0 (at :math:`s \to 1`); otherwise it is
reached at :math:`s^* = \sqrt{h_0/\beta^+}`:

.. math::

    h_1 \ge m(h_0) = \alpha + \big(\sqrt{\beta^+} - \sqrt{h_0}\big)^2
    \quad (h_0 < \beta^+), \qquad m(h_0) = \alpha \quad (h_0 \ge \beta^+).

:math:`m(0) = \alpha + \beta^+` is the old margin; it falls as the robot stands
clear of the line. A plan holding every stage at one height :math:`h` passes
when :math:`h \ge m(h)`: for :math:`\alpha \le \beta^+`,
:math:`\sqrt h \ge (\alpha + \beta^+)/(2\sqrt{\beta^+})`, i.e.
:math:`h \ge (\alpha + \beta^+)^2 / (4\beta^+)`, else :math:`h \ge \alpha`: exactly
the largest deviation :math:`L` over the sample
(:func:`~sqpmpc.problem.plant.largest_deviation`). So each decentralized robot's
shared rows keep, beyond the pair's check line (built from the true distance plus
the solver's margin, identically by both robots):

- stage 1: :math:`\max(L, m(h_0))`, :math:`h_0` measured at the sample (capped, as
  before, at the current height when the pair is inside the band);
- stages 2..N: :math:`L`.

A plan the rows accept passes the check (stage 1 keeps :math:`m(h_0)`), and the
robot starts the next sample at least :math:`L` above the line when the hyperplane
holds still, where :math:`L` is again enough; where it moved (a new plan of the
neighbour, a push) :math:`h_0 < L` and stage 1 keeps up to the old margin. Between
two robots the rows keep :math:`2L` (0.125 m at the bounds above, with the Euler
plant: :math:`L = \beta/4`) plus the solver margin, instead of
:math:`2(\alpha + \beta^+)` (:class:`RowMargins`); the first-input and braking
checks are unchanged (the bound of the input chosen), so safety does not rest on
this choice, only which plans the QP proposes does. :math:`\alpha` and
:math:`\beta^+` are their largest values over the velocity and acceleration
boxes (:func:`row_deviation`; :math:`m` and :math:`L` grow with both). The
centralized rows (both robots' positions are variables of one QP, each pair's row
at the same stage) keep the same for the pair as a whole: the pair's two paths stray
by up to :math:`2\alpha s + 2\beta s(1-s)` from its predicted segments, so stage 1
keeps :math:`\max(2L, m_2(h_0))` (:math:`m_2` the required height for
:math:`2\alpha, 2\beta`, :math:`h_0` the pair's current height above its check
line; :math:`m_2(h_0) = 2 m(h_0/2)`, each robot's half) and stages 2..N :math:`2L`
(:class:`sqpmpc.ocp.collision_rows.PairwiseCollisionModel`). They kept the old margin
until the roadmap coordination needed robots at neighbouring vertices: 0.75 m beyond
the required distance at :math:`|a| \le 3` m/s^2 and :math:`T_s` = 0.5 s, more than the
corridor built-in's starts leave. The rows against obstacles and missing neighbours
keep the old margin (:func:`~sqpmpc.problem.plant.model_margin`).
"""

from __future__ import annotations

import numpy as np

from sqpmpc.problem.plant import (
    PlantSpec,
    corner_deviations,
    largest_deviation,
    model_margin,
)

__all__ = ["RowMargins", "required_height", "row_deviation"]


def row_deviation(input_lower: np.ndarray, input_upper: np.ndarray, sample_time: float,
                  prediction: str, plant: PlantSpec,
                  acceleration_bounds: tuple[np.ndarray, np.ndarray]) -> tuple[float, float]:
    r"""The largest :math:`\alpha` and :math:`\beta^+ = \max(\beta, 0)` of
    :func:`~sqpmpc.problem.plant.acceleration_path_deviation` over the velocity and
    acceleration boxes (their corners), m.

    Examples
    --------
    Euler on Euler, :math:`|a| \le 2`, :math:`T_s = 0.5`: :math:`(0, |a|T_s^2/2)`.

    >>> lo, hi = np.array([-0.6, -0.8]), np.array([0.6, 0.8])
    >>> acc = (np.array([-2.0, -7.0]), np.array([2.0, 7.0]))
    >>> row_deviation(lo, hi, 0.5, "euler", PlantSpec(), acc)
    (0.0, 0.25)
    """
    alpha, beta = corner_deviations(input_lower, input_upper, sample_time, prediction, plant,
                                    acceleration_bounds)
    return float(alpha.max()), float(np.maximum(beta, 0.0).max())


def required_height(height: np.ndarray | float, alpha: float, beta: float) -> np.ndarray:
    r""":math:`m(h_0)`: the smallest height :math:`h_1` of the next position above the
    check line for which a path within :math:`\alpha s + \beta s(1-s)` of the segment
    from height ``height`` (:math:`h_0`, negative taken as 0) to :math:`h_1` stays
    above the line (module notes)."""
    h0 = np.maximum(np.asarray(height, dtype=float), 0.0)
    b = max(float(beta), 0.0)
    return float(alpha) + np.maximum(np.sqrt(b) - np.sqrt(h0), 0.0) ** 2


class RowMargins:
    """The margins of one controller's rows (built once by the pipeline).

    Parameters
    ----------
    input_lower, input_upper
        Velocity bounds ``(2,)``.
    sample_time, prediction, plant
        :math:`T_s`, the controller's discretization and the ``[plant]`` table.
    acceleration_bounds
        ``(lower, upper)`` of the accelerations (robots with velocity states), or
        ``None`` (the paper's robot).

    Attributes
    ----------
    model_margin
        :func:`~sqpmpc.problem.plant.model_margin`: the old margin between two robots.
    deviation
        ``(alpha_max, beta_max)`` of :func:`row_deviation` for robots with velocity
        states, else ``None``.
    steady
        :math:`L`, the largest deviation of ``deviation`` (0 without it).
    kept
        What the pair rows of either scheme keep between two robots at rest beyond the
        required distance (the solver's margin aside): ``2 steady``; 0 for the paper's
        robot.
    rules
        Beyond the required distance the rules measure *near* from
        (:attr:`sqpmpc.rules.base.RuleContext.model_margin`): ``model_margin`` for
        robots with velocity states, the most any row keeps (stage 1 of a robot on
        its check line), as the rules were tuned; 0 for the paper's robot. (Measured
        with ``kept`` instead on the physics benchmark's corridor the decentralized
        cost ratio was 1.10 instead of 1.20, but paper-s2 with ``acceleration = [-1,
        1]`` decentralized ended 0.133 m from its moving reference, outside the paper
        robot's band of 0.095 m: ``tests/test_acceleration_model.py``.)
    """

    def __init__(self, input_lower: np.ndarray, input_upper: np.ndarray,
                 sample_time: float, prediction: str, plant: PlantSpec,
                 acceleration_bounds: tuple[np.ndarray, np.ndarray] | None) -> None:
        args = (input_lower, input_upper, sample_time, prediction, plant)
        self.model_margin = model_margin(*args, acceleration_bounds)
        self.deviation = None if acceleration_bounds is None else \
            row_deviation(*args, acceleration_bounds)
        self.steady = 0.0 if self.deviation is None else float(
            largest_deviation(*self.deviation))
        self.kept = 2.0 * self.steady
        self.rules = 0.0 if acceleration_bounds is None else self.model_margin

