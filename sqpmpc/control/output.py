"""What one controller sample returns (:class:`ControlOutput`) and the braking input."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from sqpmpc.ocp.report import IterationReport

if TYPE_CHECKING:
    from sqpmpc.control.plans import PlanMessage

__all__ = ["ControlOutput", "braking_input"]


@dataclass
class ControlOutput:
    """Result of one controller sample.

    Attributes
    ----------
    inputs
        ``(m, 2)`` velocity commands ``(v, omega)`` to apply (within bounds).
    predicted_states, predicted_inputs
        ``(m, N+1, 3)`` poses and ``(m, N, 2)`` paper-unicycle inputs of the plan
        consistent with ``inputs`` (for the paper's unicycle the plan itself; for a
        model with velocity states, :meth:`~sqpmpc.models.base.RobotModel.poses` and
        :meth:`~sqpmpc.models.base.RobotModel.velocity_plan`).
    fallback
        ``None``, ``"shifted-plan"`` or ``"brake"``.
    report
        What the iteration did.
    compute_time
        Wall time of the whole sample, s.
    cpu_time
        CPU time of the calling thread over the whole sample
        (``time.thread_time``), s; unlike ``compute_time`` it does not grow with
        the machine's load (NaN where no controller step measured it).
    counters
        Cumulative counts of the controller after this sample: the engine's
        (``samples``, ``fallbacks``, ``qp_rescues``, ``stage_one_overrides``,
        ...) and every rule's (``sqpmpc rules``).
    plan
        Decentralized: the plan to send to the neighbours
        (:class:`~sqpmpc.control.plans.PlanMessage`, the same object as the
        controller's ``published``); ``None`` for the centralized controller.
    plan_ages
        Decentralized: this step's plan-age report, per late neighbour id
        (:attr:`sqpmpc.control.decentralized.DecentralizedController.plan_ages`).
    """

    inputs: np.ndarray
    predicted_states: np.ndarray
    predicted_inputs: np.ndarray
    fallback: str | None
    report: IterationReport
    compute_time: float
    counters: Mapping[str, int] = field(default_factory=dict)
    plan: PlanMessage | None = None
    plan_ages: Mapping[int, int] = field(default_factory=dict)
    model_states: np.ndarray | None = None
    model_inputs: np.ndarray | None = None
    cpu_time: float = float("nan")


def braking_input(lower: np.ndarray, upper: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The input closest to zero within ``[lower, upper]``, broadcast to ``shape + (2,)``."""
    return np.broadcast_to(np.clip(0.0, lower, upper), shape + (2,)).copy()
