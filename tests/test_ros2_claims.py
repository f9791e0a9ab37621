"""The ROS 2 mode's protections without processes: plans are claims checked against the
neighbour's past plans and bounds, a departed neighbour's disc may be left, a robot
without credentials refuses to start, a simulated base stops on its command timeout."""

from __future__ import annotations

import time

import numpy as np
import pytest

from services.messages import PlanMsg
from services.robot import main as robot_main
from services.ros2.neighbours import Neighbours
from services.ros2.simfleet import SimRobot
from services.ros2.timing import Estimate, arc

TS, N, V = 0.5, 8, 0.6


def _neighbours() -> Neighbours:
    return Neighbours([1, 2], 1, np.array([0.0, 0.3]), TS, N, V, lead=0.15, guard=0.02,
                      margin=0.02, input_bounds=(np.array([-V, -0.8]), np.array([V, 0.8])))


def _plan(start: np.ndarray, u: tuple[float, float], stamp: float) -> PlanMsg:
    """An honest plan: ``u`` held, its stages on the exact arcs."""
    states = [np.asarray(start, dtype=float)]
    for _ in range(N):
        states.append(arc(states[-1], u[0], u[1], TS))
    return PlanMsg(2, 0, 0.0, stamp, np.array(states), np.tile(u, (N, 1)))


def test_false_plans_are_refused_and_their_robot_kept_at_a_samples_reach():
    now = time.time()
    near = _neighbours()
    go = (0.4, 0.2)
    first = _plan(np.zeros(3), go, now - 0.6)
    assert near.add(first, now) is None
    # its next plan starts where the first put it one sample later: kept
    second = _plan(arc(np.zeros(3), *go, TS), go, now - 0.1)
    assert near.add(second, now) is None and near.untrusted == {}
    where = arc(second.states[0], *go, TS)
    false = {
        "starts": _plan(np.array([3.0, 0.0, 0.0]), (0.0, 0.0), now + 0.4),  # the freeze
        "second moving plan": _plan(where, go, now + 0.2),
        "outside the velocity bounds": _plan(where, (0.9, 0.0), now + 0.4),
        "before its previous plan": _plan(where, (0.0, 0.0), now - 0.3),
        "ahead of this robot's clock": _plan(where, (0.0, 0.0), now + 5.0),
    }
    for reason, msg in false.items():
        why = near.add(msg, now)
        assert why is not None and reason in why, (reason, why)
    assert near.untrusted == {2: len(false)} and "starts" in near.reasons[2]
    # the second moving plan could follow the first (not the second): a fork, two claims
    # kept (it may be on either); every other one is refused, never used
    assert near.received == 3 and [len(c) for c in near.forks[2]] == [2]
    assert near.forks[2][0][-1].stamp == now + 0.2
    # its honest next plan is still kept on its chain
    assert near.add(_plan(where, go, now + 0.4), now + 0.45) is None
    assert near.received == 4 and near.plans[2][-1].stamp == now + 0.4
    # refused claims add nothing: where it may be is its kept claims (the fork's included),
    # as for a trusted robot with the same plans and the same fork
    trusted = _neighbours()
    for msg in (first, second, false["second moving plan"], _plan(where, go, now + 0.4)):
        trusted.add(msg, now + 0.45)
    assert not trusted.untrusted.keys() - {2} and [len(c) for c in trusted.forks[2]] == [2]
    fork_end = arc(arc(np.zeros(3), *go, TS), *go, TS)  # the fork's arc from `second`'s start
    for y in (0.25, 0.45, 0.7):  # a robot standing beside either claim
        beside = np.array([where[0], where[1] + y, 0.0])
        assert near.path_is_safe(beside, np.zeros(2), now + 0.45) \
            == trusted.path_is_safe(beside, np.zeros(2), now + 0.45)
    assert not near.path_is_safe(np.array([*fork_end[:2] + [0.0, 0.2], 0.0]), np.zeros(2),
                                 now + 0.45)


def test_claims_inside_this_robot_or_far_from_the_robots_recent_plans_are_refused():
    """The freeze and herd attacks: a key holder's plan of robot 2 standing where this
    robot will be at its next instant (inside it) or far from where robot 2's plans of the
    last samples put it is refused, never kept; a fork may branch only from the plans of
    the last two samples (before, from any of the sixteen kept: metres away)."""
    now = time.time()
    near = _neighbours()
    go = (0.6, 0.0)
    at = np.array([-2.4, 0.0, 0.0])
    for k in range(8):  # four seconds of robot 2 driving along x, at full speed
        assert near.add(_plan(at, go, now - 3.75 + k * TS), now) is None
        at = arc(at, *go, TS)
    # this robot drives behind it, at (-2.6, 1) towards +x; its plan stamped now
    near.sent(now, np.array([[-2.6, 1.0, 0.0]] * (N + 1)), np.tile([0.6, 0.0], (N, 1)))
    mine = arc(np.array([-2.6, 1.0, 0.0]), 0.6, 0.0, TS)  # where it is at now + Ts
    why = near.add(_plan(mine, (0.0, 0.0), now + TS), now)  # the freeze
    assert why is not None and "inside it" in why
    # the herd: 1 m from robot 2's first arc (its reach since: 2.25 m), 2 m from its last
    why = near.add(_plan(mine + [0.35, 0.0, 0.0], (0.0, 0.0), now + TS), now)
    assert why is not None and "starts" in why
    assert near.received == 8 and near.forks[2] == [] and near.untrusted == {2: 2}
    # another move from where its newest plan starts (one plan of it may be lost) does
    # branch from the plans before it
    turn = _plan(near.plans[2][-1].states[0], (0.6, 0.5), now + 0.05)
    assert near.add(turn, now) is not None and [len(c) for c in near.forks[2]] == [8]
    # so does a move from 0.4 m off its last two arcs, within its older arcs' reach (a
    # robot whose base did not do as its plans said, in a machine stall, goes on from
    # where it truly is); standing there, it is refused (placed again by the reach later)
    assert near.add(_plan(np.array([-0.6, 0.3, 0.0]), (0.0, 0.0), now + 0.3), now) is not None
    assert len(near.forks[2]) == 1
    jump = _plan(np.array([-0.6, 0.3, 0.0]), go, now + 0.3)
    assert near.add(jump, now) is not None and len(near.forks[2]) == 2


def test_a_forged_plan_stamped_at_the_robots_next_instant_does_not_hide_its_true_one():
    """A key holder knows robot 2's next instant: a claim stamped there that arrives first
    is a second claim of that instant, not a reason to drop robot 2's own plan."""
    now = time.time()
    near = _neighbours()
    go = (0.6, 0.0)
    assert near.add(_plan(np.zeros(3), go, now - 0.5), now) is None
    end = arc(np.zeros(3), *go, TS)
    forged = _plan(end, (0.0, 0.3), now)  # turning on the spot instead: consistent
    assert near.add(forged, now) is None
    honest = _plan(end, go, now)
    assert near.add(honest, now) is not None  # kept as a fork: it may be on either
    assert [c[-1].inputs[0, 0] for c in near.forks[2]] == [0.6]
    assert near.add(honest, now) is None and near.untrusted == {2: 1}  # a repeat
    ahead = np.array([end[0] + 0.55, end[1], np.pi])  # where it drives, not the forged turn
    assert not near.path_is_safe(ahead, np.zeros(2), now)


def test_a_robot_inside_a_departed_neighbours_disc_may_leave_it_but_not_approach():
    now = time.time()
    near = _neighbours()
    near.plans[2].append(_plan(np.zeros(3), (0.0, 0.0), now - 1.0))  # as add() keeps it
    near.departed[2] = Estimate(np.zeros(3), V * TS)  # left: a sample's reach, 0.3 m
    inside = np.array([0.5, 0.0, 0.0])  # 0.2 m from the disc, 0.3 m + margin needed
    assert near.path_is_safe(inside, np.array([0.4, 0.0]), now)  # straight away
    assert near.path_is_safe(inside, np.zeros(2), now)
    assert not near.path_is_safe(inside, np.array([-0.2, 0.0]), now)  # towards it
    sideways = np.array([0.5, 0.0, np.pi / 2])
    assert not near.path_is_safe(sideways, np.array([0.4, 0.0]), now)  # round it: closer
    # far enough, the usual check: passing by is fine
    assert near.path_is_safe(np.array([1.5, 0.0, np.pi / 2]), np.array([0.4, 0.0]), now)


@pytest.mark.parametrize(("extra", "message"), [
    ([], "no credentials: the plan exchange needs --credentials DIR"),
    (["--insecure", "--zenoh-config", "x.json5"], "give --zenoh-config or --insecure"),
    (["--ros2", "--insecure", "--ros2-zenoh-config", "no-such.json5"],
     "--ros2-zenoh-config no-such.json5: no such file"),
    (["--ros2", "--insecure", "--cmd-rate", "1"], "--cmd-rate: must be above 1/Ts"),
    (["--ros2", "--insecure", "--cmd-rate", "1000"], "--cmd-rate: at most 100 Hz"),
    (["--ros2", "--insecure", "--cmd-rate", "-5"], "--cmd-rate: expected a number >= 0"),
])
def test_a_robot_without_credentials_refuses_to_start(capsys, extra, message):
    with pytest.raises(SystemExit) as exc:
        robot_main(["--id", "1", "--scenario", "paper-s2", *extra])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_a_simulated_base_stops_on_its_command_timeout_and_counts_it():
    robot = SimRobot(1, 0.3, np.zeros(3), 100.0, timeout=0.5)
    robot.command(0.4, 0.0, 100.0)
    assert not robot.expire(100.45)
    robot.command(0.4, 0.0, 100.45)  # the same command again: held, the timeout restarts
    assert not robot.expire(100.9)
    assert robot.expire(101.0) and robot.timeouts == 1
    state, vel = robot.at(102.0)
    assert vel == (0.0, 0.0)
    assert state[0] == pytest.approx(0.4 * 0.95)  # moved until 100.95, then stood
    robot.command(0.4, 0.0, 102.0)
    assert robot.timed_out == pytest.approx(102.0 - 100.95)
    # a gap seen only when the next command comes counts too
    robot.command(0.2, 0.0, 103.0)
    assert robot.timeouts == 2 and robot.at(103.0)[0][0] == pytest.approx(0.38 + 0.2)
    # standing still (zero held), a timeout does not count
    robot.command(0.0, 0.0, 103.1)
    assert not robot.expire(104.0) and robot.timeouts == 2


def test_a_simulated_base_takes_back_a_timeout_its_own_lag_caused():
    robot = SimRobot(1, 0.3, np.zeros(3), 100.0, timeout=0.5)
    robot.command(0.4, 0.0, 100.0, sent=100.0)
    assert robot.expire(100.6) and robot.timeouts == 1  # nothing processed for 0.6 s
    # the next command had been sent 0.05 s after the last (the simulator lagged): not
    # the controller's timeout
    robot.command(0.4, 0.0, 100.7, sent=100.05)
    assert robot.timeouts == 0 and robot.lagged == 1 and robot.timed_out == 0.0
    # processed late again, but judged when it comes: the lag alone is no timeout
    robot.command(0.4, 0.0, 101.5, sent=100.1)
    assert robot.timeouts == 0 and robot.lagged == 1
    # a gap in what the controller sent is one
    robot.command(0.4, 0.0, 102.2, sent=102.2)
    assert robot.timeouts == 1 and robot.lagged == 1
    assert robot.timed_out == pytest.approx(102.2 - 102.0)


@pytest.mark.parametrize("lazy", [False, True])
def test_plant_mode_refuses_a_plan_not_starting_at_its_robots_state(lazy):
    from services.messages import encode
    from services.plans import PlanStore, StepPlans
    from services.protocol import AcceptancePolicy
    from services.validator import MessageValidator

    true = {(2, 299): np.array([1.0, 2.0, 0.3]), (3, 299): np.array([-1.0, 0.0, 0.0])}
    store = PlanStore(MessageValidator([1, 2, 3], N), [2, 3], AcceptancePolicy(1000, TS, N),
                      lambda: 300, lazy=lazy, truth=lambda rid, k: true.get((rid, k)))

    def plan(rid: int, start: np.ndarray, sample: int = 299) -> bytes:
        return encode(PlanMsg(rid, sample, 1.0, 0.0, np.tile(start, (N + 1, 1)),
                              np.zeros((N, 2))))

    store.add(2, plan(2, true[2, 299] + [0.5, 0.0, 0.0]))  # robot 2 claimed 0.5 m off
    store.add(3, plan(3, true[3, 299]))
    store.add(2, plan(2, np.array([7.0, 7.0, 0.0]), 298))  # no state of 298 here: kept
    plans = StepPlans(store, 300, [2, 3])
    assert plans[3].sample == 299 and plans[2].sample == 298  # 299's refused when read
    assert store.false == {2: 1}



def test_a_forged_stop_does_not_hide_where_the_robot_goes():
    """A key holder claims robot 2 stopped at its start (consistent with its first plan);
    robot 2's own next plan contradicts that claim but follows its first plan: kept as a
    fork, and the check keeps out of both claims (before, robot 2 was believed standing
    while it drove on: a collision in the ROS 2 flood benchmark)."""
    now = time.time()
    near = _neighbours()
    go = (0.6, 0.0)
    start = np.zeros(3)
    assert near.add(_plan(start, go, now - 1.0), now) is None
    assert near.add(_plan(start, (0.0, 0.0), now - 0.8), now) is None  # the forged stop
    honest = _plan(arc(start, *go, TS), go, now - 0.5)
    why = near.add(honest, now)
    assert why is not None and "contradicting" in why and near.untrusted == {2: 1}
    assert [c[-1].stamp for c in near.forks[2]] == [now - 0.5]
    # within the sample's reach of where robot 2 drives (0.6 m on at `now`), clear of all the
    # forged stop allows
    ahead = np.array([1.0, 0.3, 0.0])
    assert not near.path_is_safe(ahead, np.zeros(2), now)
    near.forks[2].clear()  # the forged stop alone: robot 2 would be hidden
    assert near.path_is_safe(ahead, np.zeros(2), now)
