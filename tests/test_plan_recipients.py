"""The sender's recipients and the receiver's slots come from one neighbour selection.

Two real robot services (each its own Zenoh session on 127.0.0.1, multicast
scouting off) on a plant that differs from the prediction (``exact``), where
the rows keep ``collision_margin + model_margin``: a robot must address its
plan to every robot that may give it a slot at the next sample.
"""

from __future__ import annotations

import numpy as np
import pytest

from services.messages import PlanMsg
from services.robot import RobotNode, build_parser
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.settings import SolverSettings
from sqpmpc.problem.fleets import antipodal_swap
from sqpmpc.problem.plant import PlantSpec
from sqpmpc.problem.scenario_file import load_scenario


def _node(path: str, robot_id: int, run: str) -> RobotNode:
    args = build_parser().parse_args(
        ["--id", str(robot_id), "--scenario", path, "--run", run, "--neighbour-slots", "1",
         "--log-level", "ERROR"])
    return RobotNode(load_scenario(path), args)


def test_a_robot_sends_its_plan_to_a_robot_that_gives_it_a_slot_on_an_exact_plant(tmp_path):
    scenario = load_scenario("head-on").with_changes(plant=PlantSpec("exact"))
    path = tmp_path / "head-on-exact.toml"
    path.write_text(scenario.to_toml())
    sender = _node(str(path), 1, "recipients")
    receiver = _node(str(path), 2, "recipients")
    try:
        assert receiver.controller.model_margin > 0.0  # the exact plant's deviation
        v_max, ts = receiver.controller.context.max_speed, scenario.sample_time
        # the receiver slots the sender up to its interaction radius; at the next sample
        # both may have closed in by v_max Ts each
        radius = float(receiver.controller.interaction_radius[0])
        now = np.array([[0.0, 0.0, 0.0], [radius + 2.0 * v_max * ts, 0.0, np.pi]])
        nxt = now.copy()
        nxt[0, 0] += v_max * ts
        nxt[1, 0] -= v_max * ts
        assert receiver.needed(nxt) == [1]  # robot 2 gives robot 1 a slot at k + 1
        plan = PlanMsg(1, 0, 0.0, 0.0, np.zeros((scenario.horizon + 1, 3)),
                       np.zeros((scenario.horizon, 2)))
        sender.publish_plan(plan, now)
        assert sender.addressed == 1  # ... so robot 1 addressed its plan of k to robot 2
    finally:
        sender.close()
        receiver.close()


@pytest.mark.parametrize("seed", range(3))
def test_every_selector_addresses_the_robots_that_slot_it(seed: int) -> None:
    """Without Zenoh: 12 robots on an exact plant, 3 slots each, random states and any
    motion within v_max Ts per robot; a robot that slots j at k + 1 is among the robots
    j's selector addresses at k."""
    scenario = antipodal_swap(12).with_changes(plant=PlantSpec("exact"))
    settings = SolverSettings(neighbour_slots=3)
    controllers = [DecentralizedController(scenario, int(rid), settings)
                   for rid in scenario.ids]
    selectors = [c.selector for c in controllers]
    assert controllers[0].model_margin > 0.0
    rng = np.random.default_rng(seed)
    v_max, ts = controllers[0].context.max_speed, scenario.sample_time
    now = np.zeros((12, 3))
    now[:, :2] = rng.normal(scale=2.0 + seed, size=(12, 2))
    sent = {j: set(s.recipients(now).tolist()) for j, s in enumerate(selectors)}
    assert sum(map(len, sent.values())) < 12 * 11  # something was filtered
    for _ in range(20):
        angle = rng.uniform(0, 2 * np.pi, 12)
        step = v_max * ts * rng.choice([0.0, 1.0, rng.uniform()], size=12)
        nxt = now.copy()
        nxt[:, 0] += step * np.cos(angle)
        nxt[:, 1] += step * np.sin(angle)
        for i, s in enumerate(selectors):
            for j in s.others[s.select(nxt).slotted]:
                assert i in sent[int(j)], (i, int(j))
