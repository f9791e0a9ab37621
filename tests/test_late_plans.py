"""Late and lost plans in the decentralized controller: the age margin, and safety."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.controllers import DecentralizedController
from sqpmpc.metrics import compute_metrics
from sqpmpc.scenario import load_scenario
from sqpmpc.simulation import ClosedLoopSimulation, SimulationOptions


def test_the_margin_grows_with_the_age_of_the_newest_plan():
    scenario = load_scenario("paper-s2")
    ts, horizon = scenario.sample_time, scenario.horizon
    ctrl = {int(i): DecentralizedController(scenario, int(i)) for i in scenario.ids}
    v_max = ctrl[1].context.max_speed
    x = scenario.initial_states()
    plans: dict = {}
    for k in range(14):
        for c in ctrl.values():
            c.step(k, k * ts, x, plans)
        # robot 1's margins at step k: robot 2's newest plan is of sample min(k - 1, 1)
        margins = dict(zip([jid for _, jid in ctrl[1]._neighbours],
                           ctrl[1].collisions.age_margin, strict=True))
        assert margins[2] == pytest.approx(v_max * ts * min(max(k - 2, 0), horizon))
        assert margins[3] == margins[4] == 0.0
        # robot 2's plans reach the others up to sample 1, then are lost
        plans = {i: c.published for i, c in ctrl.items() if i != 2 or k < 2}
    assert ctrl[1].counts["late_plan_neighbours"] == 14 - 3


@pytest.mark.parametrize("name", ["paper-s2", "swap-6"])
def test_lost_plans_never_cause_a_collision(name):
    scenario = load_scenario(name)
    scenario = scenario.with_changes(t_end=min(scenario.t_end, 80 * scenario.sample_time))
    sim = ClosedLoopSimulation(scenario, "decentralized",
                               options=SimulationOptions(message_drop_probability=0.5, seed=3))
    rec = sim.run()
    m = compute_metrics(rec)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert rec.extra["counters"]["late_plan_neighbours"] > 0
    assert np.isfinite(rec.states).all()
