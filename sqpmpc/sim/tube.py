r"""How far a robot's true path left the tube its controller checked.

The first-input checks hold for the robot's true path over a sample when it stays
within the deviation bound :math:`\alpha s + \beta s(1-s)` of the predicted
segment, from the measured position to the plan's stage 1
(:mod:`sqpmpc.problem.plant`). :func:`tube_excursion` measures how far a path
sampled within the samples (the physics plant's steps, :mod:`sqpmpc.sim.physics`)
went beyond it: 0 where the checks' assumption held.
"""

from __future__ import annotations

import numpy as np

from sqpmpc.problem.plant import PlantSpec, acceleration_path_deviation, path_deviation

__all__ = ["tube_excursion"]


def tube_excursion(path: np.ndarray, states: np.ndarray, horizons: np.ndarray,
                   commands: np.ndarray, velocities: np.ndarray | None, sample_time: float,
                   prediction: str, plant: PlantSpec) -> float:
    r"""The largest distance of a true path beyond the checked tube, m (0 inside it).

    Parameters
    ----------
    path
        ``(K, S, n, 2)``: the robots' positions at the fractions ``(1..S)/S`` of each of
        ``K`` samples.
    states
        ``(K+1, n, 3+)`` measured poses at the samples.
    horizons
        ``(K, n, N+1, 3)`` the plans' poses (stage 1: the predicted next position).
    commands
        ``(K, n, 2)`` the commanded :math:`(v, \omega)`.
    velocities
        ``(K, n, 2)`` measured :math:`(v_0, \omega_0)` at the samples (robots with
        acceleration bounds: the plan's accelerations are ``(command - v0) / Ts``), or
        ``None`` (the paper's robot).
    sample_time, prediction, plant
        :math:`T_s`, the controller's discretization and the scenario's ``[plant]``.

    Examples
    --------
    A robot exactly on its predicted segment:

    >>> path = np.array([[[[0.5, 0.0]], [[1.0, 0.0]]]])
    >>> states = np.array([[[0.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]]])
    >>> plan = np.array([[[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]]])
    >>> tube_excursion(path, states, plan, np.array([[[2.0, 0.0]]]), None, 0.5, "euler",
    ...                PlantSpec())
    0.0
    """
    h = float(sample_time)
    if velocities is not None:
        alpha, beta = acceleration_path_deviation(
            velocities, (commands - velocities) / h, h, prediction, plant.model,
            plant.noise_bound)
    else:  # a plant that lags: from the commands of the samples before (at rest at first)
        previous = np.concatenate((np.zeros_like(commands[:1]), commands[:-1]), axis=0)
        alpha, beta = path_deviation(commands, h, prediction, plant.model, plant.noise_bound,
                                     plant if plant.response else None, previous)
    steps = path.shape[1]
    s = (np.arange(1, steps + 1) / steps)[None, :, None]               # (1, S, 1)
    seg = (1.0 - s)[..., None] * states[:-1, None, :, :2] + s[..., None] * horizons[:, None, :,
                                                                                   1, :2]
    bound = alpha[:, None] * s + beta[:, None] * s * (1.0 - s)
    out = np.linalg.norm(path - seg, axis=-1) - bound
    return float(max(out.max(initial=0.0), 0.0))
