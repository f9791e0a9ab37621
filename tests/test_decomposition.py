"""The oracle-prediction run of ``benchmarks.decomposition`` and the paper-mode warning."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from benchmarks.decomposition import OraclePredictionSimulation
from sqpmpc.control import decentralized
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.ocp.collision_rows import SHARED
from sqpmpc.problem.scenario_file import load_scenario


def test_oracle_plans_reach_every_robot_unshifted() -> None:
    """Each robot's predictions (own row and neighbours') are the centralized plan of this
    sample (stage N is recomputed from its last state and input, to rounding)."""
    sim = OraclePredictionSimulation(load_scenario("paper-s2"))
    for _ in range(3):
        sim.step()
    k, x = sim.k, sim.states[sim.k]
    plan = sim.oracle.step(sim.t[k], x)
    sim.hand_out(k, plan)
    for j, c in enumerate(sim.controllers):
        c.predict_neighbours(k, x, sim.neighbour_plans, sim.states[k - 1])
        assert c.collisions.kind.tolist() == [SHARED] * (sim.scenario.n_robots - 1)
        # predictions of stages 1..N
        np.testing.assert_allclose(c.own_prediction, plan.predicted_states[j][1:], rtol=0,
                                   atol=1e-12)
        for e, other in enumerate(c.others):
            np.testing.assert_allclose(c.slot_data.predictions[e],
                                       plan.predicted_states[other][1:], rtol=0, atol=1e-12)
    sim.step()
    assert compute_metrics(sim.record())["collisions"] == 0


def test_paper_mode_warns_once(caplog: pytest.LogCaptureFixture,
                               monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(decentralized, "paper_mode_warned", False)
    sc = load_scenario("head-on")
    with caplog.at_level(logging.WARNING, logger="sqpmpc.control.decentralized"):
        DecentralizedController(sc, 1, mode="paper")
        DecentralizedController(sc, 2, mode="paper")
        DecentralizedController(sc, 1)
    warnings = [r for r in caplog.records if "no collision guarantee" in r.getMessage()]
    assert len(warnings) == 1
