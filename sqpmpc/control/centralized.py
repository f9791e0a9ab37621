"""The centralized controller (paper Algorithm 3.1): one QP for every robot of the scenario.
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np

from sqpmpc.control.pipeline import ControllerPipeline, ControlOutput
from sqpmpc.control.plans import PlanAges
from sqpmpc.control.settings import SolverSettings
from sqpmpc.kernels.pair_paths import pairs_keep_ramp_distance, ramp_vectors
from sqpmpc.ocp.collision_rows import PairwiseCollisionModel
from sqpmpc.ocp.obstacle_rows import scenario_map_slots
from sqpmpc.problem.plant import acceleration_path_deviation
from sqpmpc.problem.scenario import Scenario
from sqpmpc.qp.layout import QPLayout
from sqpmpc.rules.registry import default_rules

__all__ = ["CentralizedController", "has_position_bounds"]


def has_position_bounds(scenario: Scenario) -> bool:
    """Whether the scenario bounds the positions (the QP then has position rows)."""
    b = scenario.bounds
    return bool(np.isfinite(b.position_lower()).any() or np.isfinite(b.position_upper()).any())


class CentralizedController(ControllerPipeline):
    """One QP over all robots (paper Algorithm 3.1, eq. 7).

    Parameters
    ----------
    scenario
        The problem.
    settings
        Solver settings (default: :class:`SolverSettings` with every rule).
    """

    scheme = "centralized"

    def __init__(self, scenario: Scenario, settings: SolverSettings | None = None) -> None:
        settings = (settings or SolverSettings(rules=default_rules(scenario))).resolved(
            scenario.n_robots, "centralized", bool(scenario.robot_model().velocity_states))
        pairs = scenario.pairs().reshape(-1, 2)
        required = scenario.required_distances()[pairs[:, 0], pairs[:, 1]]
        layout = QPLayout(scenario.n_robots, scenario.horizon, pairs,
                          sum(scenario_map_slots(scenario)), has_position_bounds(scenario),
                          scenario.robot_model())
        super().__init__(scenario, np.arange(scenario.n_robots), layout, settings)
        self.pairs = pairs
        self.required = required
        self.collisions = PairwiseCollisionModel(
            pairs, required, self.pair_margin, self.geometry, self.recovery_tolerance,
            deviation=self.margins.deviation, base_margin=settings.collision_margin)
        self._rows = {"internal": self.collisions}
        if self.obstacle_rows is not None:
            self._rows["external"] = self.obstacle_rows
        self._sample = 0
        self._keep = np.array(self.collisions.safe_distance, dtype=float)
        # the neighbour slots of the decentralized scheme, per robot, for the pair rows
        self.slots = settings.neighbour_slots
        self.interaction_radius = (required + self.pair_margin + 2.0
                                   * self.context.max_speed * scenario.horizon
                                   * scenario.sample_time)
        if self.slots is not None:
            self.counts["stage_one_pairs"] = 0

    def predict_neighbours(self, sample: int, states: np.ndarray, plans: Mapping[int, object],
                           previous_states: np.ndarray | None,
                           plan_ages: PlanAges | None = None) -> None:
        """The pair rows from the current positions (the neighbours' data are unused: every
        robot is in this QP)."""
        self.collisions.set_current_positions(states[:, :2])
        if self.model.velocity_states:
            self._keep = self.kept_distances(states)
        if self.slots is not None:
            _, first_only = self.collisions.select(self.interaction_radius, self.slots)
            self.counts["stage_one_pairs"] += first_only

    def kept_distances(self, states: np.ndarray) -> np.ndarray:
        """Per pair, the distance the checks of robots with velocity states keep this sample
        from the measured ``states (n, nx)``: the required distance, or with the
        ``overlap-recovery`` rule on, for a pair already inside it (a push, a slip), its
        current distance less the rule's tolerance (it must come no closer, along the
        first input's path and the braking after it), so that inputs which separate it
        are applied instead of a brake that never ends."""
        keep = np.array(self.collisions.safe_distance, dtype=float)
        if self.collisions.recovery >= 0.0:
            p = states[:, :2]
            gap = np.linalg.norm(p[self.pairs[:, 0]] - p[self.pairs[:, 1]], axis=-1)
            inside = gap < keep
            keep[inside] = np.maximum(gap[inside] - self.collisions.recovery, 0.0)
        return keep

    def first_input_safe(self, states: np.ndarray, next_states: np.ndarray,
                         inputs: np.ndarray) -> bool:
        """Every pair keeps its distance along the paths of the sample.

        With the Euler model the robots move on straight segments at constant
        speed, so checking the relative segments (not only the next sample)
        keeps robots from passing through each other between samples. A plant
        that moves otherwise (an arc, noise) strays from the predicted segment
        by at most :meth:`path_deviation`, which the check adds.
        """
        alpha, beta = self.path_deviation(inputs)
        now = np.ascontiguousarray(states[:, :2])
        p = np.ascontiguousarray(next_states[:, :2])
        if not self._unicycle:  # robots with velocity states: the bound itself
            ramp = ramp_vectors(states[:, 2], inputs[:, 0], self.sample_time)
            if not pairs_keep_ramp_distance(self.collisions.pairs, now, p, ramp,
                                            self._keep, alpha, beta):
                return False
            return self.obstacles_safe(now, p, alpha, beta) and self.in_position_bounds(p)
        if self._response is not None:
            # a plant that lags: the bound itself (its lag part grows at the speed change's
            # rate near s = 0 and is a fraction of that by s = 1, far below the linear
            # majorant), pairs inside their distance by the overlap-recovery rule alone
            if not (self.collisions.first_input_safe(now, p, np.zeros_like(alpha))
                    and self._apart_pairs_keep(now, p, alpha, beta)):
                return False
            return self.obstacles_safe(now, p, alpha, beta) and self.in_position_bounds(p)
        # alpha + max(beta, 0) (alpha itself, bit for bit, when the plant moves as predicted)
        growth = alpha + np.maximum(beta, 0.0) if self._deviates else alpha
        if not self.collisions.first_input_safe(now, p, growth):
            return False
        return self.obstacles_safe(now, p, growth) and self.in_position_bounds(p)

    def _apart_pairs_keep(self, now: np.ndarray, nxt: np.ndarray, alpha: np.ndarray,
                          beta: np.ndarray) -> bool:
        """The pairs apart now keep their distance over the sample when each robot's path
        strays up to ``alpha s + beta s (1 - s)`` from its segment (exactly: Bernstein
        bounds on the squared distance, :mod:`sqpmpc.kernels.pair_paths`)."""
        pairs, keep = self.collisions.pairs, self.collisions.safe_distance
        gap = np.linalg.norm(now[pairs[:, 0]] - now[pairs[:, 1]], axis=-1)
        apart = gap >= keep
        return bool(pairs_keep_ramp_distance(
            np.ascontiguousarray(pairs[apart]), now, nxt, np.zeros_like(now), keep[apart],
            np.ascontiguousarray(alpha, dtype=float), np.ascontiguousarray(beta, dtype=float)))

    def _brakes_safely(self, next_states: np.ndarray) -> bool:
        """With acceleration limits: braking right after the first input, every robot as hard
        as its limits allow, keeps every pair's distance along the braking paths.

        If it does, the braking fallback of the next sample (all robots brake from where
        the first input took them) follows a path checked here: the fallback is safe by
        induction, as standing still is for the paper's unicycle (which stops at once).
        The obstacles are checked along the same paths as they move on.
        Each braking sample's true path may stray from its segment by the bound of
        :func:`~sqpmpc.problem.plant.acceleration_path_deviation`.
        """
        if not self.model.velocity_states:
            return True
        path, inputs = self.braking_path(next_states)
        alpha, beta = acceleration_path_deviation(
            path[:, :-1, 3:5], inputs, self.sample_time, self.settings.discretization,
            self.scenario.plant.model, self._noise_bound)                    # (m, B) each
        for j in range(inputs.shape[1]):
            now = np.ascontiguousarray(path[:, j, :2])
            nxt = np.ascontiguousarray(path[:, j + 1, :2])
            ramp = ramp_vectors(path[:, j, 2], inputs[:, j, 0], self.sample_time)
            if not pairs_keep_ramp_distance(self.collisions.pairs, now, nxt, ramp, self._keep,
                                            np.ascontiguousarray(alpha[:, j]),
                                            np.ascontiguousarray(beta[:, j])):
                return False
        return self.obstacle_rows is None or self.obstacle_rows.braking_safe(path[..., :2],
                                                                             alpha, beta)

    def step(self, t: float, states: np.ndarray, sample: int | None = None) -> ControlOutput:
        """Inputs of every robot at time ``t`` from the measured ``states (n, 3)``.

        Parameters
        ----------
        t
            Time ``t_k``, s.
        states
            Measured states of all robots (scenario order): ``(n, 3)`` poses, or ``(n, 5)``
            with the measured ``(v, omega)`` appended (CONTRACT 1c; with poses alone a robot
            with acceleration limits is taken to move at what it was last commanded).
        sample
            Sample index ``k`` (default: one more than the last call's, 0 at first).

        Returns
        -------
        ControlOutput
            ``inputs (n, 2)`` to apply (scenario order) and the plan behind them.
        """
        k = self._sample if sample is None else int(sample)
        cpu = time.thread_time()
        out = self.run_sample(k, t, states)
        out.cpu_time = time.thread_time() - cpu
        self._sample = k + 1
        return out
