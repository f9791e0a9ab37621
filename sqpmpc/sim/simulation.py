r"""Closed-loop simulation of either scheme in one process.

The plant integrates the unicycle with the chosen discretization (by default
the controller's, so that the paper's setting is reproduced exactly). At
every sample ``k`` the controller(s) see the measured states
:math:`\chi(k)`; decentralized controllers see the plans their neighbours
published at ``k - 1`` (all robots compute in parallel), optionally with
messages dropped at random to exercise the paper's communication fallback,
or delivered ``plan_delay`` samples after they were computed (as the
services' fault injector ``SQPMPC_FAULTS="delay=D"`` does). Each robot's
``plan_ages`` of step ``k - 1`` are handed to every controller at ``k``, as
the services' plant relays them with the states.

A run that stops midway (exception, Ctrl-C) keeps what it had:
:meth:`ClosedLoopSimulation.record` returns the partial record at any time.
"""

from __future__ import annotations

import logging
import os
from collections import deque
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from tqdm.auto import tqdm

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.plans import PlanMessage
from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.problem.plant import Plant
from sqpmpc.problem.scenario import Scenario
from sqpmpc.rules.registry import default_rules
from sqpmpc.sim.record import RunRecord

__all__ = ["ClosedLoopSimulation", "SimulationOptions", "simulate"]

log = logging.getLogger(__name__)
Scheme = Literal["centralized", "decentralized"]


@dataclass(frozen=True)
class SimulationOptions:
    """Options of a closed-loop run.

    Attributes
    ----------
    decentralized_mode
        ``"shared"`` or ``"paper"``.
    plant_discretization
        ``None``: the scenario's ``[plant] model`` (``"euler"`` without one);
        else ``"euler"``, ``"rk4"`` or ``"exact"`` in its place (its input noise kept).
    message_drop_probability
        Decentralized only: probability that a plan message is lost.
    plan_delay
        Decentralized only: a plan computed at sample ``k`` reaches the
        neighbours for their step ``k + plan_delay`` (default 1: the next
        sample, no delay).
    seed
        Seed of the message-loss generator.
    progress
        Show a progress bar (appears after two seconds).
    """

    decentralized_mode: str = "shared"
    plant_discretization: str | None = None
    message_drop_probability: float = 0.0
    plan_delay: int = 1
    seed: int = 0
    progress: bool = False

    def __post_init__(self) -> None:
        if (isinstance(self.plan_delay, bool) or not isinstance(self.plan_delay, int)
                or not 1 <= self.plan_delay <= 1000):
            raise ProblemError(f"plan_delay must be an integer in 1..1000 (samples), got "
                               f"{self.plan_delay!r}")
        if not 0.0 <= self.message_drop_probability <= 1.0:
            raise ProblemError(
                f"message_drop_probability must be in [0, 1], got {self.message_drop_probability}"
            )


class ClosedLoopSimulation:
    """Closed loop of a scenario with one scheme.

    Parameters
    ----------
    scenario
        The problem.
    scheme
        ``"centralized"`` or ``"decentralized"``.
    settings
        Controller settings.
    options
        Simulation options.
    """

    def __init__(self, scenario: Scenario, scheme: Scheme,
                 settings: SolverSettings | None = None,
                 options: SimulationOptions | None = None) -> None:
        if scheme not in ("centralized", "decentralized"):
            raise ProblemError(f"scheme must be 'centralized' or 'decentralized', got {scheme!r}")
        self.scenario = scenario
        self.scheme = scheme
        self.settings = settings or SolverSettings(rules=default_rules(scenario))
        self.options = options or SimulationOptions()
        n, K = scenario.n_robots, scenario.steps
        spec = scenario.plant
        if self.options.plant_discretization is not None:
            spec = replace(spec, model=self.options.plant_discretization)
            scenario = scenario.with_changes(plant=spec)
            self.scenario = scenario
        self.plant_method = spec.model
        limits = (scenario.bounds.acceleration_lower(), scenario.bounds.acceleration_upper()) \
            if scenario.bounds.dynamic_limits else None
        self.plant = Plant(spec, scenario.sample_time, n, limits)
        if scheme == "centralized":
            self.controllers = [CentralizedController(scenario, self.settings)]
        else:
            self.controllers = [
                DecentralizedController(scenario, int(i), self.settings,
                                        self.options.decentralized_mode)
                for i in scenario.ids
            ]
        self.t = scenario.sample_time * np.arange(K + 1)
        self.states = np.zeros((K + 1, n, 3))
        self.states[0] = scenario.initial_states()
        self.inputs = np.zeros((K, n, 2))
        self.plant_inputs = np.zeros((K, n, 2))
        self.horizons = np.full((K, n, scenario.horizon + 1, 3), np.nan)  # the plans
        self.solve_times = np.zeros((K, len(self.controllers)))
        self.cpu_times = np.zeros((K, len(self.controllers)))
        self.k = 0
        self.fallbacks = 0
        self.kkt_failures = 0
        self.qp_iterations = 0
        self.sqp_iterations = np.zeros(K, dtype=np.int64)
        self.timing = {"assembly_s": 0.0, "qp_s": 0.0, "osqp_solve_s": 0.0, "total_s": 0.0}
        self.neighbour_plans: dict[int, PlanMessage] = {}
        self._in_transit: deque[tuple[int, dict[int, PlanMessage]]] = deque()
        self._plan_ages: dict[int, dict[int, int]] = {}
        self._rng = np.random.default_rng(self.options.seed)
        self.dropped_messages = 0
        #: ids of the robots whose controllers left the run (:meth:`depart`)
        self.departed: set[int] = set()

    # -------------------------------------------------------------- stepping
    def depart(self, robot_id: int) -> None:
        """Robot ``robot_id``'s controller leaves the run for good (decentralized): from the
        next step on it computes nothing and publishes nothing, its robot is sent zero
        (it stops within its bounds and stands), and every other controller is told
        (:meth:`~sqpmpc.control.pipeline.ControllerPipeline.update_departed`), as a plant
        tells the controllers of a distributed run.

        Raises
        ------
        ProblemError
            The centralized scheme (one controller drives every robot), or an id that is
            not a robot of the scenario.
        """
        if self.scheme != "decentralized":
            raise ProblemError("depart: only a decentralized run has a controller per robot")
        self.scenario.index_of(int(robot_id))  # a robot of the scenario, or a named error
        self.departed.add(int(robot_id))
        for c in self.controllers:
            if c.robot_id not in self.departed:
                c.update_departed(sorted(self.departed))

    def step(self) -> None:
        """Advance one sample."""
        k, sc = self.k, self.scenario
        if k >= sc.steps:
            raise ProblemError("the simulation has already reached t_end")
        x = self.states[k]
        measured = self.plant.measure(x)  # with acceleration bounds: poses and velocities
        prev = self.states[k - 1] if k > 0 else None
        if self.scheme == "centralized":
            out = self.controllers[0].step(self.t[k], measured)
            u = out.inputs
            outs = [out]
        else:
            while self._in_transit and self._in_transit[0][0] <= k:
                # a lost message leaves the receivers with the older plan, as over a network
                self.neighbour_plans.update(self._in_transit.popleft()[1])
            taking_part = [c for c in self.controllers if c.robot_id not in self.departed]
            outs = [c.step(k, self.t[k], measured, self.neighbour_plans, prev, self._plan_ages)
                    for c in taking_part]
            if self.departed:  # a departed robot is sent nothing: it stops, and stands
                u = np.zeros((sc.n_robots, 2))
                self.horizons[k] = x[:, None, :]
                for c, o in zip(taking_part, outs, strict=True):
                    j = sc.index_of(c.robot_id)
                    u[j] = o.inputs[0]
                    self.horizons[k, j] = o.predicted_states[0]
            else:
                u = np.concatenate([o.inputs for o in outs], axis=0)
                self.horizons[k] = np.concatenate([o.predicted_states for o in outs], axis=0)
            self._plan_ages = {c.robot_id: c.plan_ages for c in taking_part if c.plan_ages}
            plans = {}
            for c in taking_part:
                if self._rng.random() < self.options.message_drop_probability:
                    self.dropped_messages += 1
                    continue
                plans[c.robot_id] = c.published
            self._in_transit.append((k + self.options.plan_delay, plans))
        if self.scheme == "centralized":
            self.horizons[k] = np.concatenate([o.predicted_states for o in outs], axis=0)
            columns = [0]
        else:
            columns = [j for j, c in enumerate(self.controllers)
                       if c.robot_id not in self.departed]
        for j, o in zip(columns, outs, strict=True):
            self.solve_times[k, j] = o.compute_time
            self.cpu_times[k, j] = o.cpu_time
            self.fallbacks += o.fallback is not None
            self.qp_iterations += o.report.qp_iterations
            self.sqp_iterations[k] += o.report.iterations
            self.timing["assembly_s"] += o.report.assembly_time
            self.timing["qp_s"] += o.report.qp_time
            self.timing["osqp_solve_s"] += o.report.osqp_solve_time
            self.timing["total_s"] += o.compute_time
        self.inputs[k] = u
        self.states[k + 1], self.plant_inputs[k] = self.plant.step(x, u)
        self.k = k + 1

    def run(self) -> RunRecord:
        """Run to ``t_end`` (continuing from where it stopped) and return the record."""
        bar = tqdm(total=self.scenario.steps, initial=self.k, disable=not self.options.progress,
                   delay=2.0, desc=f"{self.scenario.name} {self.scheme}", unit="sample",
                   leave=False)
        try:
            while self.k < self.scenario.steps:
                self.step()
                bar.update(1)
        finally:
            bar.close()
        return self.record()

    def counters(self) -> dict[str, int]:
        """The controllers' counters summed (engine and rules, see ``sqpmpc rules``)."""
        total: dict[str, int] = {}
        for c in self.controllers:
            for key, value in c.counters().items():
                total[key] = total.get(key, 0) + int(value)
        return total

    def record(self) -> RunRecord:
        """The record of what has been simulated so far (partial if interrupted)."""
        k = self.k
        extra = {
            "decentralized_mode": self.options.decentralized_mode
            if self.scheme == "decentralized" else None,
            "iteration_scheme": self.settings.iteration_scheme,
            "hessian": self.settings.hessian,
            "discretization": self.settings.discretization,
            "plant_discretization": self.plant_method,
            "collision_margin": self.settings.collision_margin,
            "model_margin": self.controllers[0].model_margin,
            "qp_iterations_total": int(self.qp_iterations),
            "counters": self.counters(),
            "rules": [r.name for r in self.settings.rules],
            "sqp_iterations_total": int(self.sqp_iterations[:k].sum()),
            "dropped_messages": int(self.dropped_messages),
            "timing_breakdown_s": {key: float(v) for key, v in self.timing.items()},
            # the machine's load when the record is taken (the run's end): wall times
            # (solve_times) grow with it, CPU times (cpu_times) do not
            "load_average": [float(v) for v in os.getloadavg()],
            "cpus": os.cpu_count(),
        }
        return RunRecord(
            scenario=self.scenario,
            scheme=self.scheme,
            t=self.t[: k + 1].copy(),
            states=self.states[: k + 1].copy(),
            inputs=self.inputs[:k].copy(),
            solve_times=self.solve_times[:k].copy(),
            solver_failures=int(self.fallbacks),
            completed=k == self.scenario.steps,
            extra=extra,
            plant_inputs=self.plant_inputs[:k].copy() if self.plant.spec.noisy
            or self.plant.has_velocities else None,
            horizons=self.horizons[:k].copy(),
            cpu_times=self.cpu_times[:k].copy(),
        )


def simulate(scenario: Scenario, scheme: Scheme, settings: SolverSettings | None = None,
             options: SimulationOptions | None = None) -> RunRecord:
    """Run a whole closed loop; see :class:`ClosedLoopSimulation`."""
    return ClosedLoopSimulation(scenario, scheme, settings, options).run()
