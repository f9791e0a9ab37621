"""The motion a robot tracks along its roadmap path (sqpmpc.coordination.motion): within
the roadmap's reach and the robot's bounds, turning in place at rest, following a path
that steps back in its order; and the QP that tracks it (its positions and inputs as
references) has a feasible motion, linearized there, as its optimum."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.coordination.motion import path_motion, smooth_path
from sqpmpc.models.acceleration import AccelerationUnicycle
from sqpmpc.models.paper import UnicycleModel
from tests.rule_helpers import fleet, only

T, N = 0.2, 12
V_MAX, W_MAX, ACCEL = 1.0, math.pi / 2, 2.0


def _grid_walk(rng: np.random.Generator, steps: int, h: float = 0.5) -> np.ndarray:
    """A random walk on a grid of spacing ``h`` (turns, straights and steps back)."""
    moves = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], dtype=float) * h
    points = [np.zeros(2)]
    for _ in range(steps):
        points.append(points[-1] + moves[rng.integers(4)])
    return np.array(points)


def _distance_to_polyline(p: np.ndarray, points: np.ndarray) -> float:
    a, b = points[:-1], points[1:]
    d = b - a
    dd = np.einsum("ij,ij->i", d, d)
    f = np.clip(np.einsum("ij,ij->i", p - a, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    return float(np.hypot(*(a + f[:, None] * d - p).T).min())


@pytest.mark.parametrize("reach", [0.0, 0.03, 0.06, 0.2])
def test_rounded_corners_stay_within_the_reach_and_headings_follow_the_path(
        reach: float) -> None:
    rng = np.random.default_rng(1)
    for _ in range(30):
        points = _grid_walk(rng, 8)
        xy, psi, marks = smooth_path(points, reach, 0.05)
        assert marks.shape == (points.shape[0],)
        for p in xy:
            assert _distance_to_polyline(p, points) <= reach + 1e-9
        step = np.diff(xy, axis=0)
        moving = np.hypot(*step.T) > 1e-9
        # on the lines and arcs the heading is the direction of travel (an arc's chord: half
        # of the sample's turn away)
        direction = np.arctan2(step[moving, 1], step[moving, 0])
        mid = 0.5 * (psi[:-1] + psi[1:])[moving]
        gap = np.abs((direction - mid + np.pi) % (2 * np.pi) - np.pi)
        assert gap.max() <= 0.5 * np.pi / 16 + 1e-9
        assert np.abs(np.diff(psi)).max() <= np.pi + 1e-9  # continuous (a half-turn at most)


@pytest.mark.parametrize("acceleration", [ACCEL, None])
def test_the_motion_keeps_the_bounds_and_stays_on_the_path(acceleration: float | None) -> None:
    rng = np.random.default_rng(2)
    reach = 0.06
    for trial in range(60):
        points = _grid_walk(rng, 6)
        heading = float(rng.uniform(-np.pi, np.pi))
        pose = np.array([*(points[0] + rng.uniform(-0.03, 0.03, 2)), heading])
        speed = 0.0 if trial % 2 else float(rng.uniform(0.0, V_MAX))
        m = path_motion(points, pose, speed, reach, T, N, V_MAX, W_MAX, acceleration)
        assert m.poses.shape == (N + 1, 3) and m.velocities.shape == (N + 1, 2)
        np.testing.assert_array_equal(m.poses[0], pose)
        v, w = m.velocities.T
        assert v.min() >= 0.0 and v.max() <= V_MAX + 1e-9
        assert np.abs(np.diff(m.poses[:, 2])).max() <= W_MAX * T + 1e-9
        travel = np.hypot(*np.diff(m.poses[1:, :2], axis=0).T)
        assert travel.max() <= V_MAX * T + 1e-9
        if acceleration is not None and speed == 0.0:
            assert np.abs(np.diff(v)).max() <= acceleration * T + 1e-9
        for p in m.poses[1:, :2]:
            assert _distance_to_polyline(p, points) <= reach + 1e-9


def test_a_robot_at_rest_facing_away_turns_in_place_then_goes() -> None:
    points = np.array([[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [1.5, 0.0]])
    m = path_motion(points, np.array([0.0, 0.0, 3.0]), 0.0, 0.06, T, 20, V_MAX, W_MAX, ACCEL)
    turning = math.ceil(3.0 / (W_MAX * T))  # samples to turn 3 rad
    np.testing.assert_allclose(m.poses[:turning, :2], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.diff(m.poses[:turning, 2]), -W_MAX * T, rtol=1e-9)
    assert m.poses[-1, 0] > 0.5 and abs(m.poses[-1, 2]) < 1e-9


@pytest.mark.parametrize(("pose", "speed"), [((0.5, 0.1, -0.3), 0.0),
                                           ((0.1, -0.127, 0.083), 0.26),
                                           ((0.5, 0.2, 0.0), 0.8)])
def test_a_robot_out_of_the_tube_rejoins_its_path_turning_towards_it(
        pose: tuple[float, float, float], speed: float) -> None:
    """Pushed farther off its path than the 0.06 m reach, at rest or moving along it: the
    offset only shrinks, the heading stays between the robot's own and the join's, which
    is at most 45 degrees off the path (a unicycle moves where it faces: a motion that
    slides sideways while it turns away from the path is one it cannot make), within the
    turn-rate bound, and it ends on the path going along it."""
    points = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    m = path_motion(points, np.array(pose), speed, 0.06, T, 30, V_MAX, W_MAX, ACCEL)
    off = np.abs(m.poses[:, 1])
    assert np.all(np.diff(off) <= 1e-12)  # the offset only shrinks
    towards = -math.copysign(1.0, pose[1])  # the side of the path
    low, high = sorted((min(towards * pose[2], 0.0), math.pi / 4))
    turned = towards * m.poses[:, 2]
    assert turned.min() >= low - 1e-9 and turned.max() <= high + 1e-9
    assert np.abs(np.diff(m.poses[:, 2])).max() <= W_MAX * T + 1e-9
    assert m.poses[-1, 0] > 1.5 and abs(m.poses[-1, 1]) < 1e-9 and abs(m.poses[-1, 2]) < 1e-9


def test_a_robot_beside_its_path_starts_from_where_it_is() -> None:
    """At rest 0.05 m beside the path (inside a 0.06 m reach), facing along it: the first
    stage is a move it can make (no sideways jump onto the path: at most a_max T^2 / 2 of
    travel from rest), and it joins the path within the reach."""
    points = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    pose = np.array([0.3, 0.05, 0.0])
    m = path_motion(points, pose, 0.0, 0.06, T, 30, V_MAX, W_MAX, ACCEL)
    assert math.hypot(*(m.poses[1, :2] - pose[:2])) <= 0.5 * ACCEL * T ** 2 + 1e-9
    assert np.all(np.diff(m.poses[:, 1]) <= 1e-12)  # the offset only shrinks
    assert abs(m.poses[-1, 1]) < 1e-9 and m.poses[-1, 0] > 1.5


def test_backwards_is_forwards_turned_by_a_half_turn() -> None:
    """A point 0.3 m behind a robot that may reverse: it backs up to it, never turning."""
    here = np.array([1.0, 0.0, 0.0])
    m = path_motion(np.array([[1.0, 0.0], [0.7, 0.0]]), here, 0.0, 0.06, T, 20, V_MAX,
                    W_MAX, ACCEL, reverse=True)
    np.testing.assert_array_equal(m.poses[0], here)
    assert m.velocities[:, 0].max() <= 0.0 and m.velocities[:, 0].min() < 0.0
    np.testing.assert_allclose(m.poses[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(m.poses[-1, :2], [0.7, 0.0], atol=1e-12)
    ahead = path_motion(np.array([[1.0, 0.0], [0.7, 0.0]]), np.array([1.0, 0.0, math.pi]),
                        0.0, 0.06, T, 20, V_MAX, W_MAX, ACCEL)
    np.testing.assert_allclose(m.poses[:, :2], ahead.poses[:, :2], atol=1e-12)
    np.testing.assert_allclose(m.velocities[:, 0], -ahead.velocities[:, 0], atol=1e-12)


def test_the_motion_stops_at_the_end_of_the_open_path() -> None:
    points = np.array([[0.0, 0.0], [0.5, 0.0], [0.5, 0.5]])
    m = path_motion(points, np.array([0.0, 0.0, 0.0]), 0.0, 0.06, T, 40, V_MAX, W_MAX, ACCEL)
    np.testing.assert_allclose(m.poses[-1, :2], [0.5, 0.5], atol=1e-12)
    assert m.velocities[-1, 0] == 0.0
    going = path_motion(points, np.array([0.0, 0.0, 0.0]), 0.0, 0.06, T, 40, V_MAX, W_MAX,
                        ACCEL, stop=False)
    assert going.velocities[-1, 0] > 0.0 or np.allclose(going.poses[-1, :2], [0.5, 0.5])


def test_a_step_back_is_followed_in_order_without_turning_twice() -> None:
    """A plan that steps back (A, B, A): a robot at B facing the way it came turns half a
    turn once and heads back, however its projection ties between the two segments."""
    points = np.array([[0.0, 0.0], [0.5, 0.0], [0.0, 0.0]])
    m = path_motion(points, np.array([0.5, 0.0, 0.0]), 0.0, 0.06, T, 30, V_MAX, W_MAX, ACCEL,
                    within=2)
    total = m.poses[-1, 2] - m.poses[0, 2]
    assert abs(abs(total) - np.pi) < 1e-9
    assert np.all(np.diff(m.poses[:, 2]) * np.sign(total) >= -1e-12)  # one way
    np.testing.assert_allclose(m.poses[-1, :2], [0.0, 0.0], atol=1e-12)


def test_the_models_states_of_a_motion_roll_out_to_its_velocities() -> None:
    points = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    m = path_motion(points, np.array([0.0, 0.0, 0.0]), 0.0, 0.06, T, N, V_MAX, W_MAX, ACCEL)
    accel = AccelerationUnicycle(np.array([-V_MAX, -W_MAX]), np.array([V_MAX, W_MAX]),
                                 np.array([-ACCEL, -10.0]), np.array([ACCEL, 10.0]))
    states, inputs = accel.motion_states(m.poses, m.velocities, T)
    assert states.shape == (N + 1, 5) and inputs.shape == (N, 2)
    np.testing.assert_allclose(states[0, 3:] + T * np.cumsum(inputs, axis=0), states[1:, 3:],
                               atol=1e-12)
    paper = UnicycleModel(np.array([-V_MAX, -W_MAX]), np.array([V_MAX, W_MAX]))
    poses, velocities = paper.motion_states(m.poses, m.velocities, T)
    np.testing.assert_array_equal(poses, m.poses)
    np.testing.assert_allclose(velocities, 0.5 * (m.velocities[:-1] + m.velocities[1:]))


def test_tracking_a_feasible_motion_reproduces_it_and_clearing_restores_the_paper_cost(
        ) -> None:
    """Reference solution: linearized at a rollout whose positions are the references and
    whose inputs are the input references, the QP's optimum is that rollout (cost 0)."""
    sc = fleet([[0.0, 0.0, 0.0]], [[3.0, 1.0]], horizon=N, sample_time=T)
    ctrl = CentralizedController(sc, only())
    ctrl.step(0.0, sc.initial_states())
    engine = ctrl.engine
    x0 = np.array([[0.1, 0.0, 0.2]])
    rng = np.random.default_rng(3)
    u = np.column_stack((rng.uniform(0.1, 0.5, N), rng.uniform(-0.5, 0.5, N)))[None]
    states = engine.rollout(x0, u)
    engine.set_guess(x0, u, converge_first=False)  # linearized at the motion itself
    engine.start_sample(x0)
    engine.update_motion(np.array([0]), states, u)
    report = engine.solve(x0, states[:, 1:, :2], started=True)
    assert report.success
    np.testing.assert_allclose(engine.inputs(), u, atol=2e-3)
    L = engine.layout
    np.testing.assert_allclose(engine.qp.q[L.input_index[0]],
                               -2.0 * np.asarray(sc.weights.R) * u[0], rtol=1e-12)
    engine.clear_motion()
    np.testing.assert_array_equal(engine.qp.q[L.input_index], 0.0)


def test_a_tracked_motion_linearizes_the_dynamics_and_the_iterate_keeps_the_rows() -> None:
    """Update-vs-rebuild: the first QP of a sample with a motion has the dynamics rows of
    the motion's rollout (as a QP whose iterate is that rollout) and the collision rows of
    the iterate (as a QP without the motion), whose iterate is not moved; the sample's
    next QP is linearized at its iterate again."""
    sc = fleet([[0.0, 0.0, 0.0], [2.0, 0.0, math.pi]], [[0.0, 3.0], [2.0, -3.0]],
               horizon=N, sample_time=T)
    x0 = sc.initial_states()

    def at_rest() -> CentralizedController:
        ctrl = CentralizedController(sc, only())
        ctrl.step(0.0, x0)
        ctrl.engine.set_guess(x0, np.zeros((2, N, 2)), converge_first=False)
        ctrl.engine.start_sample(x0)
        return ctrl

    def solve(ctrl: CentralizedController) -> None:
        assert ctrl.engine.solve(x0, reference, max_iterations=1, started=True,
                                 internal=ctrl.collisions).success

    # robot 0 faces east and must go north: the motion turns in place, then drives
    tracked, along, plain = at_rest(), at_rest(), at_rest()
    motion = path_motion(np.array([[0.0, 0.0], [0.0, 1.0], [0.0, 2.0]]), x0[0], 0.0, 0.06,
                         T, N, float(sc.bounds.v[1]), float(sc.bounds.omega[1]), None)
    states, u = tracked.engine.model.motion_states(motion.poses[None],
                                                   motion.velocities[None], T)
    reference = np.repeat(x0[:, None, :2], N, axis=1)
    reference[0] = motion.poses[1:, :2]
    tracked.engine.update_motion(np.array([0]), states, u)
    np.testing.assert_array_equal(tracked.engine.z, plain.engine.z)  # the iterate stays
    solve(tracked)
    L = along.engine.layout  # rebuilt: an iterate that is the motion's rollout
    along.engine.z[L.state_index[0]] = along.engine.rollout(x0[:1], u)[0]
    along.engine.z[L.input_index[0]] = u[0]
    solve(along)
    solve(plain)
    for name, source in (("dyn_A", along), ("dyn_B", along), ("internal", plain)):
        np.testing.assert_allclose(tracked.engine.qp.matrix_entries(name),
                                   source.engine.qp.matrix_entries(name), rtol=0, atol=1e-12,
                                   err_msg=name)
    for k in (0, 1):
        np.testing.assert_allclose(tracked.engine.qp.row_bounds("dyn")[k],
                                   along.engine.qp.row_bounds("dyn")[k], atol=1e-12)
    # the turn is seen: the predicted positions leave the heading's line (east) northwards;
    # at rest the QP cannot see it, its positions stay on the line y = 0
    predicted = tracked.engine.states_inputs()[0][0, -1]
    flat = plain.engine.states_inputs()[0][0, -1]
    assert abs(flat[1]) < 1e-3 and predicted[1] > 0.5 * motion.poses[-1, 1] > 0.0
    # the motion's point is spent: the next QP of the sample is linearized at the iterate
    for ctrl in (tracked, plain):
        ctrl.engine.set_guess(x0, np.zeros((2, N, 2)), converge_first=False)
        ctrl.engine.start_sample(x0)
        solve(ctrl)
    np.testing.assert_allclose(tracked.engine.qp.matrix_entries("dyn_A"),
                               plain.engine.qp.matrix_entries("dyn_A"), rtol=0, atol=1e-12)
