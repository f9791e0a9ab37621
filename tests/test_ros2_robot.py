"""The ROS 2 robot's pieces without processes: bad options, committed motion of plans, the
controller's check, the neighbours' headings and the plans awaited."""

from __future__ import annotations

import numpy as np
import pytest

from services.robot import build_parser
from services.robot import main as robot_main
from services.ros2.options import odom_timeout, ros2_problem
from services.ros2.timing import TimedPlan, arc, committed, plan_position
from sqpmpc.problem.scenario_file import load_scenario


@pytest.mark.parametrize(("args", "message"), [
    (["--id", "1", "--id", "2"], "--ros2 drives one robot"),
    (["--id", "1", "--ros2-namespace", "robot1"], "absolute ROS 2 name"),
    (["--id", "1", "--ros2-namespace", "/9lives"], "absolute ROS 2 name"),
    (["--id", "1", "--ros2-domain", "300"], "--ros2-domain: expected 0..232"),
    (["--id", "1", "--epoch", "5", "--epoch-file", "x"], "--epoch or --epoch-file"),
    (["--id", "1", "--lead", "0.6"], "--lead: must be less than Ts"),
    (["--id", "1", "--odom-timeout", "0.5"], "--odom-timeout: must be less than Ts"),
    (["--id", "1", "--decentralized-mode", "paper"], "--decentralized-mode"),
])
def test_bad_ros2_options_are_one_clear_error(capsys, args, message):
    with pytest.raises(SystemExit) as exc:
        robot_main([*args, "--scenario", "paper-s2", "--ros2"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "Traceback" not in err[0]


def test_the_default_odometry_timeout_follows_the_sample_time():
    """0.6 Ts: a scenario of Ts = 0.2 s (every one `sqpmpc generate mapf` writes) is not
    refused for a default it cannot change (the default was a fixed 0.3 s)."""
    sc = load_scenario("paper-s2").with_changes(sample_time=0.2)
    args = build_parser().parse_args(["--id", "1", "--scenario", "paper-s2", "--ros2"])
    assert odom_timeout(args, sc) == pytest.approx(0.12)
    problem = ros2_problem(args, sc)
    assert problem is None or "odom-timeout" not in problem


def test_committed_motion_is_the_first_arc_then_held_or_bounded():
    Ts, v_max = 0.5, 0.6
    states = np.array([[0.0, 0.0, 0.0]] * 9)
    inputs = np.array([[0.4, 0.3]] * 8)
    plans = [TimedPlan(10.0, states, inputs), TimedPlan(10.5, states + [1.0, 0.0, 0.0], inputs)]
    times = np.array([9.8, 10.2, 10.5, 10.7, 11.0, 11.4])
    pos, rad = committed(plans, times, Ts, v_max, hold_after=False)
    assert np.allclose(pos[1], arc(states[0], 0.4, 0.3, 0.2)[:2])
    assert np.allclose(pos[3], arc(plans[1].states[0], 0.4, 0.3, 0.2)[:2])
    assert rad[1] == rad[2] == rad[3] == rad[4] == 0.0
    assert np.isclose(rad[5], v_max * 0.4)  # 0.4 s past the newest plan's first sample
    assert np.isclose(rad[0], v_max * 0.2)  # before the oldest plan
    held, rad_held = committed(plans, times, Ts, v_max, hold_after=True)
    assert rad_held[5] == 0.0 and np.allclose(held[5], held[4])
    # a lost plan leaves a gap: bounded by the reach from the older arc's end
    gap, rad_gap = committed([plans[0], TimedPlan(11.5, states, inputs)], np.array([11.2]),
                             Ts, v_max, hold_after=True)
    assert np.isclose(rad_gap[0], v_max * 0.7)
    assert np.allclose(gap[0], arc(states[0], 0.4, 0.3, Ts)[:2])
    assert np.allclose(plan_position(plans[0], 10.2, Ts)[:2], pos[1])


def test_the_check_keeps_out_of_all_a_neighbour_may_stop_on():
    import time

    from services.messages import PlanMsg
    from services.ros2.neighbours import Neighbours

    now = time.time()
    near = Neighbours([1, 2], 1, np.array([0.0, 0.3]), 0.5, 8, 0.6, lead=0.15, guard=0.02,
                      margin=0.02)
    states = np.zeros((9, 3))
    states[:, 0] = 0.3 * np.arange(9)
    near.add(PlanMsg(2, 0, 0.0, now - 0.2, states, np.tile([0.6, 0.0], (8, 1))), now)
    assert near.received == 1
    go = np.array([0.6, 0.0])
    assert near.path_is_safe(np.array([0.0, 0.5, 0.0]), go, now)  # side by side
    assert near.path_is_safe(np.array([0.0, 0.5, 0.0]), np.zeros(2), now)
    # 0.35 m behind it: it may stop where it was 0.2 s ago, so following is refused
    assert not near.path_is_safe(np.array([-0.35, 0.0, 0.0]), go, now)
    assert near.path_is_safe(np.array([-0.35, 0.0, 0.0]), np.zeros(2), now)
    # a plan from the future is refused (its robot untrusted), a copy ignored; another plan
    # of the same instant is a second claim
    assert "ahead of this robot's clock" in near.add(
        PlanMsg(2, 5, 0.0, now + 10.0, states, np.zeros((8, 2))), now)
    assert near.add(PlanMsg(2, 0, 0.0, now - 0.2, states, np.tile([0.6, 0.0], (8, 1))),
                    now) is None
    assert (near.received, near.untrusted) == (1, {2: 1})
    assert near.add(PlanMsg(2, 0, 0.0, now - 0.2, states, np.zeros((8, 2))), now) is not None
    assert near.untrusted == {2: 2}


def test_the_controller_checks_as_the_robot_and_waits_for_plans_in_flight():
    import time

    from services.control import controller_settings
    from services.messages import PlanMsg
    from services.robot import build_parser
    from services.ros2.controller import Ros2Controller
    from services.ros2.neighbours import Neighbours
    from sqpmpc.problem.scenario_file import load_scenario

    scenario = load_scenario("paper-s2")
    ids = [int(i) for i in scenario.ids]
    me, other = ids[0], ids[1]
    settings = controller_settings(build_parser().parse_args(
        ["--id", str(me), "--scenario", "paper-s2", "--ros2"]))
    controller = Ros2Controller(scenario, me, settings)
    now = time.time()
    nb = Neighbours(ids, me, scenario.required_distances()[0], 0.5, scenario.horizon,
                    float(controller.context.max_speed), lead=0.15, guard=0.02, margin=0.02)
    controller.neighbours = nb
    own = np.array(scenario.initial_states()[0], dtype=float)
    # a neighbour standing 0.5 m ahead on the own way to the reference, facing it
    goal = scenario.reference_positions(0.0)[0]
    ahead = own[:2] + 0.5 * (goal - own[:2]) / np.hypot(*(goal - own[:2]))
    heading = float(np.arctan2(*(own[:2] - ahead)[::-1]))
    standing = np.tile([*ahead, heading], (scenario.horizon + 1, 1))
    nb.add(PlanMsg(other, 0, 0.0, now - 0.1, standing, np.zeros((scenario.horizon, 2))), now)
    t = now + 0.1
    others, plans = nb.for_controller(t, 0)
    assert np.isclose(others[1, 2], heading)  # the rules see its heading (roundabout)
    states = others.copy()
    states[0] = own
    controller.check_time = t
    out = controller.step(0, 0.0, states, plans, None)
    # what the controller applies passes the robot's check: the QP's input, the shifted
    # plan or standing still (then its plan stands where it is)
    assert nb.path_is_safe(own, out.inputs[0], t)
    if out.fallback == "brake":
        assert np.allclose(out.inputs[0], 0.0)
    # the neighbour's next instant (now + 0.4) comes before one at now + 0.45: decided at
    # now + 0.25, its plan is awaited from then on, not before; a robot deciding after
    # this one (its instant later than this one's) is not
    assert not nb.awaited(own, now + 0.45, now)
    assert nb.awaited(own, now + 0.45, now + 0.26)
    assert not nb.awaited(own, now + 0.35, now + 0.26)
    nb.add(PlanMsg(other, 1, 0.0, now + 0.4, standing, np.zeros((scenario.horizon, 2))),
           now + 0.27)
    assert not nb.awaited(own, now + 0.45, now + 0.27)  # it came
