"""Late and lost plans in the decentralized controller: the age margin, shared rows from an
agreed older pair of plans, and safety (in process and in the services)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from services.faults import ENV
from services.testing import free_ports, start_service, stop_processes
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.plans import pair_sample, predict_from_states
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.models.unicycle import discrete_dynamics
from sqpmpc.ocp.collision_rows import MISSING, SHARED
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import ClosedLoopSimulation, SimulationOptions
from tests import HANG


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
        margins = dict(zip([jid for _, jid in ctrl[1].slot_data.neighbours],
                           ctrl[1].collisions.age_margin, strict=True))
        assert margins[2] == pytest.approx(v_max * ts * min(max(k - 2, 0), horizon))
        assert margins[3] == margins[4] == 0.0
        # robot 2's plans reach the others up to sample 1, then are lost
        plans = {i: c.published for i, c in ctrl.items() if i != 2 or k < 2}
    assert ctrl[1].counts["late_plan_neighbours"] == 14 - 3


def test_a_departed_neighbour_keeps_no_age_margin_and_its_braked_reach():
    """A neighbour told departed (its plant brakes it) has no age margin however old its
    last plan, and from the second sample on its one-sample reach is what it moved over the
    sample before: 0 standing, in the rows and in the check; a neighbour merely silent
    keeps the full reach and the growing margin."""
    scenario = load_scenario("paper-s2")
    ts = scenario.sample_time
    ctrl = {int(i): DecentralizedController(scenario, int(i)) for i in scenario.ids}
    reach = ctrl[1].context.max_speed * ts
    x = scenario.initial_states()
    plans: dict = {}
    for k in range(6):
        if k == 3:
            ctrl[1].update_departed([2])  # robot 2 left; robot 3 goes silent too
        for i, c in ctrl.items():
            if i != 2 or k < 3:
                c.step(k, k * ts, x, plans, x if k else None)
        plans = {i: c.published for i, c in ctrl.items() if i not in (2, 3) or k < 2}
        d = ctrl[1].slot_data
        slot = {jid: e for e, jid in d.neighbours}
        rows = ctrl[1].collisions
        if k >= 3:  # robot 2 departed: no margin; standing (x held): reach 0 after a sample
            assert rows.age_margin[slot[2]] == 0.0
            assert rows.slot_reach[slot[2]] == (reach if k == 3 else 0.0)
        assert rows.slot_reach[slot[3]] == reach
        if k >= 4:
            assert rows.age_margin[slot[3]] > 0.0  # silent, not departed
    ctrl[1].update_departed([])  # back: the full reach again
    ctrl[1].step(6, 6 * ts, x, plans, x)
    assert ctrl[1].collisions.slot_reach[{j: e for e, j in ctrl[1].slot_data.neighbours}[2]] \
        == reach


def test_missing_neighbours_are_predicted_each_as_alone():
    """The paper's fallback for the slots without a plan, computed in one rollout, is each
    neighbour's own prediction exactly: standing at the first sample, the input estimated
    from two states when the plans are lost."""
    scenario = load_scenario("paper-s2")
    ts, horizon = scenario.sample_time, scenario.horizon
    ctrl = DecentralizedController(scenario, int(scenario.ids[0]))
    x0 = scenario.initial_states()
    x1 = x0.copy()
    x1[:, :2] += 0.1 * np.column_stack((np.cos(x0[:, 2]), np.sin(x0[:, 2])))
    x1[:, 2] += 0.05
    for k, states, previous in ((0, x0, None), (1, x1, x0)):
        ctrl.step(k, k * ts, states, {}, previous)  # no plan from anyone
        d = ctrl.slot_data
        slots = [e for e, _ in d.neighbours]
        assert slots and all(d.kinds[e] == MISSING for e in slots)
        for e in slots:
            j = d.index[e]
            alone = predict_from_states(states[j], None if previous is None else previous[j],
                                        horizon, ts, ctrl.settings.discretization)[1:]
            assert np.array_equal(d.predictions[e], alone)


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


def _arrived(rec, scenario, tolerance: float = 0.05) -> np.ndarray:
    k = rec.states.shape[0] - 1
    goal = scenario.reference_positions(k * scenario.sample_time)
    return np.hypot(*(rec.states[-1, :, :2] - goal).T) <= tolerance


@pytest.mark.parametrize("name", ["head-on", "swap-6"])
def test_plans_two_samples_late_share_older_rows_and_every_robot_arrives(name):
    # without the relayed plan ages no row is shared and these encounters jam (3-4 m short)
    scenario = load_scenario(name)
    sim = ClosedLoopSimulation(scenario, "decentralized", options=SimulationOptions(plan_delay=2))
    rec = sim.run()
    m = compute_metrics(rec)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert _arrived(rec, scenario).all()
    assert rec.extra["counters"]["older_shared_neighbours"] > 0


def test_both_robots_of_a_pair_build_the_same_row_whatever_the_delays():
    # every plan reaches each receiver 1 to 3 samples late (drawn per message and
    # receiver); whenever both robots of a pair share a row, it is one line: opposite
    # normals, halves adding up to the distance, first-stage checks adding up to it
    scenario = load_scenario("swap-6").with_changes(t_end=20.0)
    ts, n = scenario.sample_time, scenario.n_robots
    ctrl = [DecentralizedController(scenario, int(i)) for i in scenario.ids]
    ids = [c.robot_id for c in ctrl]
    rng = np.random.default_rng(4)
    x = scenario.initial_states()
    in_transit: list[tuple[int, int, object]] = []  # (due sample, receiver, plan)
    ages: dict[int, dict[int, int]] = {}
    required = scenario.required_distances()
    margin = ctrl[0].settings.collision_margin
    shared_pairs = older = 0
    for k in range(scenario.steps):
        for _due, r, plan in [t for t in in_transit if t[0] <= k]:
            ctrl[r].update_neighbour_plan(plan)
        in_transit = [t for t in in_transit if t[0] > k]
        outs = [c.step(k, k * ts, x, None, None, ages) for c in ctrl]
        ages = {c.robot_id: dict(c.plan_ages) for c in ctrl if c.plan_ages}
        for a in range(n):
            for b in range(a + 1, n):
                ea = dict((j, e) for e, j in ctrl[a].slot_data.neighbours)[ids[b]]
                eb = dict((j, e) for e, j in ctrl[b].slot_data.neighbours)[ids[a]]
                ca, cb = ctrl[a].collisions, ctrl[b].collisions
                if not (ca.kind[ea] == SHARED and cb.kind[eb] == SHARED):
                    continue
                shared_pairs += 1
                older += pair_sample(k, ids[a], ids[b], None) != pair_sample(k, ids[a], ids[b],
                                                                            ages or None)
                np.testing.assert_array_equal(ca.fixed_normals[ea], -cb.fixed_normals[eb])
                np.testing.assert_array_equal(ca.check_normals[ea], -cb.check_normals[eb])
                first = 2 if ca.touching[ea] else 1  # a touching pair holds stage 2 alone
                np.testing.assert_allclose(ca.fixed_rhs[ea, first:] + cb.fixed_rhs[eb, first:],
                                           required[a, b] + margin, rtol=0, atol=1e-9)
                gap = float(ca.check_normals[ea] @ (x[a, :2] - x[b, :2]))
                assert ca.check_rhs[ea] + cb.check_rhs[eb] == pytest.approx(
                    min(required[a, b], gap), abs=1e-9)
        for r, c in enumerate(ctrl):
            for other in range(n):
                if other != r:
                    in_transit.append((k + int(rng.integers(1, 4)), other, c.published))
        x = np.array([discrete_dynamics(x[j], outs[j].inputs[0], ts, "euler")
                      for j in range(n)])
    assert shared_pairs > 100 and older > 0


def test_services_with_plans_two_samples_late_arrive_without_collision(tmp_path):
    # the plant and one process per robot over Zenoh on loopback, every plan held back 2
    # samples by the transport's fault injector: the plan ages ride on the inputs and the
    # states, and the head-on pair passes instead of holding each other off
    ports = free_ports(3)
    plant_ep = f"tcp/127.0.0.1:{ports[0]}"
    common = ["--scenario", "head-on", "--run", "late"]
    env = {**os.environ, ENV: "delay=2,kinds=plan"}
    plant = start_service("plant", [*common, "--listen", plant_ep, "--out",
                                    str(tmp_path / "out"), "--no-plots", "--timeout", "5"],
                          tmp_path / "logs", env=env)
    robots = [start_service("robot", ["--id", str(i), *common, "--insecure", "--listen",
                                      f"tcp/127.0.0.1:{port}", "--connect", plant_ep,
                                      "--timeout", "0.2"],
                            tmp_path / "logs", name=f"robot-{i}", env=env)
              for i, port in zip((1, 2), ports[1:], strict=True)]
    try:
        assert plant.wait(HANG) == 0, plant.output()
        for r in robots:
            assert r.wait(HANG) == 0, r.output()
    finally:
        stop_processes([plant, *robots])
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["completed"] is True
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["counters"]["older_shared_neighbours"] > 0
    scenario = load_scenario("head-on")
    final = np.load(tmp_path / "out" / "trajectory.npz")["states"][-1, :, :2]
    goal = scenario.reference_positions(scenario.steps * scenario.sample_time)
    assert (np.hypot(*(final - goal).T) <= 0.05).all()
