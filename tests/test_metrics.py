"""Metrics of a run record and the run output files, on hand-computed cases."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from sqpmpc.errors import ProblemError
from sqpmpc.io.files import load_trajectory, write_metrics, write_run, write_trajectory
from sqpmpc.io.metrics import compute_metrics, intersample_distances
from sqpmpc.problem.scenario import Scenario
from sqpmpc.sim.record import RunRecord
from tests.scenarios import goal_scenario

CONTRACT_KEYS = {
    "scenario", "scheme", "steps", "sample_time", "horizon", "min_distance", "min_clearance",
    "collisions", "rms_tracking_error", "closed_loop_cost", "input_bound_violations",
    "solver_failures", "solve_time",
}


def make_record(scenario: Scenario, positions, inputs=None, solve_times=None,
                **kwargs) -> RunRecord:
    """A record with the given (k+1, n, 2) positions, heading 0, zero inputs by default."""
    pos = np.asarray(positions, dtype=float)
    k = pos.shape[0] - 1
    n = pos.shape[1]
    states = np.concatenate([pos, np.zeros((k + 1, n, 1))], axis=-1)
    inputs = np.zeros((k, n, 2)) if inputs is None else np.asarray(inputs, dtype=float)
    solve_times = np.full((k, 1), 1e-3) if solve_times is None else solve_times
    return RunRecord(scenario=scenario, scheme=kwargs.pop("scheme", "centralized"),
                     t=np.arange(k + 1) * scenario.sample_time, states=states, inputs=inputs,
                     solve_times=solve_times, **kwargs)


def two_robots() -> Scenario:
    # Required distance (0.4 + 0.6) / 2 = 0.5.
    return goal_scenario(np.array([[0.0, 0.0], [1.0, 0.0]]), diameters=(0.4, 0.6))


def test_pair_distance_clearance_and_collisions() -> None:
    # Robot 2 at distance 1.0, then exactly 0.5 (touching, safe), then 0.3 (overlap).
    pos = [[[0, 0], [1.0, 0]], [[0, 0], [0.3, 0.4]], [[0, 0], [0.3, 0.0]]]
    m = compute_metrics(make_record(two_robots(), pos))
    assert m["min_distance"] == pytest.approx(0.3)
    assert m["min_clearance"] == pytest.approx(-0.2)
    assert m["collisions"] == 1
    assert m["min_clearance_at"] == {"t": 2.0, "pair": [1, 2]}


def test_robots_passing_through_each_other_between_samples_collide() -> None:
    # the samples are 0.6 m apart (safe), but the straight segments cross at the same time
    pos = [[[0, 0], [0.6, 0]], [[0.6, 0], [0.0, 0]]]
    m = compute_metrics(make_record(two_robots(), pos))
    assert m["collisions"] == 0 and m["min_clearance"] == pytest.approx(0.1)
    assert m["intersample_collisions"] == 1
    assert m["intersample_min_clearance"] == pytest.approx(-0.5)
    # passing side by side 0.5 apart: touching, not a collision
    pos = [[[0, 0], [0.6, 0.5]], [[0.6, 0], [0.0, 0.5]]]
    m = compute_metrics(make_record(two_robots(), pos))
    assert m["intersample_collisions"] == 0
    assert m["intersample_min_clearance"] == pytest.approx(0.0, abs=1e-12)


def test_intersample_distances_are_the_exact_segment_minimum() -> None:
    rng = np.random.default_rng(4)
    pos = rng.normal(size=(30, 3, 2))
    pairs = np.array([[0, 1], [0, 2], [1, 2]])
    exact = intersample_distances(pos, pairs)
    s = np.linspace(0.0, 1.0, 4001)[:, None, None, None]
    path = (1 - s) * pos[None, :-1] + s * pos[None, 1:]  # (S, 29, 3, 2)
    dense = np.linalg.norm(path[..., pairs[:, 0], :] - path[..., pairs[:, 1], :], axis=-1)
    dense = dense.min(axis=0)
    assert exact.shape == (29, 3)
    assert np.all(exact <= dense + 1e-12)
    np.testing.assert_allclose(exact, dense, atol=1e-6)
    # standing still: the minimum is the sample distance
    still = np.repeat(pos[:1], 2, axis=0)
    np.testing.assert_allclose(intersample_distances(still, pairs)[0],
                               np.linalg.norm(pos[0, pairs[:, 0]] - pos[0, pairs[:, 1]], axis=-1))


def test_collision_tolerance() -> None:
    pos = [[[0, 0], [0.5 - 5e-7, 0]], [[0, 0], [0.5 - 2e-6, 0]]]
    m = compute_metrics(make_record(two_robots(), pos))
    assert m["collisions"] == 1
    assert m["min_clearance"] == pytest.approx(-2e-6, abs=1e-12)


def test_required_distance_per_pair() -> None:
    sc = goal_scenario(np.zeros((3, 2)), diameters=(0.2, 0.4, 1.0))
    # Pair (1, 2) needs 0.3 at 0.35; (1, 3) needs 0.6 at 0.5: clearance -0.1;
    # (2, 3) needs 0.7 at 0.85.
    pos = [[[0, 0], [0.35, 0], [-0.5, 0]]]
    m = compute_metrics(make_record(sc, pos))
    assert m["min_distance"] == pytest.approx(0.35)
    assert m["min_clearance"] == pytest.approx(-0.1)
    assert m["collisions"] == 1
    assert m["min_clearance_at"]["pair"] == [1, 3]


def test_closed_loop_cost_rms_and_final_error_by_hand() -> None:
    sc = goal_scenario(np.array([[1.0, 1.0]]), diameters=(0.3,),
                      Q=(1.0, 2.0), R=(0.5, 3.0))
    pos = [[[0.0, 0.0]], [[0.5, 1.0]], [[1.0, 0.0]]]
    inputs = [[[0.5, 0.1]], [[0.2, -0.2]]]
    m = compute_metrics(make_record(sc, pos, inputs=inputs))
    # e1 = (0.5, 0): 0.25; e2 = (0, 1): 2; u0: 0.125 + 0.03; u1: 0.02 + 0.12. p0 not counted.
    assert m["closed_loop_cost"] == pytest.approx(0.25 + 2.0 + 0.155 + 0.14)
    # Errors sqrt(2), 0.5, 1 -> RMS sqrt((2 + 0.25 + 1) / 3).
    assert m["rms_tracking_error"] == {"1": pytest.approx(math.sqrt(3.25 / 3))}
    assert m["final_position_error"] == {"1": pytest.approx(1.0)}
    assert m["max_final_position_error"] == pytest.approx(1.0)
    # Single robot: no pairs.
    assert m["min_distance"] is None and m["min_clearance"] is None
    assert m["collisions"] == 0


def test_moving_reference_uses_record_times() -> None:
    sc = goal_scenario(np.array([[0.0, 0.0]]), velocities=np.array([[1.0, 0.0]]),
                      diameters=(0.3,), sample_time=0.5)
    pos = [[[0.0, 0.0]], [[0.5, 0.0]], [[1.0, 0.0]]]  # exactly on r(t) = (t, 0)
    m = compute_metrics(make_record(sc, pos))
    assert m["rms_tracking_error"]["1"] == pytest.approx(0.0)
    assert m["closed_loop_cost"] == pytest.approx(0.0)


def test_input_bound_violations_tolerance() -> None:
    sc = goal_scenario(np.zeros((2, 2)), diameters=(0.1, 0.1))
    pos = np.zeros((3, 2, 2))
    pos[:, 1, 0] = 1.0
    inputs = [
        [[0.6 + 5e-10, 0.8], [-0.6, -0.8 - 5e-10]],      # within tolerance
        [[0.6 + 2e-9, 0.0], [0.0, -0.8 - 1e-8]],         # two violations
    ]
    m = compute_metrics(make_record(sc, pos, inputs=inputs))
    assert m["input_bound_violations"] == 2


def test_state_bound_violations() -> None:
    sc = goal_scenario(np.zeros((1, 2)), diameters=(0.3,),
                      x_bounds=(-1.0, 1.0))
    m = compute_metrics(make_record(sc, [[[0.0, 50.0]], [[1.0 + 1e-10, 0.0]], [[1.5, 0.0]]]))
    assert m["state_bound_violations"] == 1


def test_solve_time_centralized() -> None:
    pos = np.zeros((4, 2, 2))
    pos[:, 1, 0] = 1.0
    st = np.array([[0.001], [0.003], [0.002]])
    m = compute_metrics(make_record(two_robots(), pos, solve_times=st))["solve_time"]
    assert m["total_s"] == pytest.approx(0.006)
    assert m["median_ms"] == pytest.approx(2.0)
    assert m["max_ms"] == pytest.approx(3.0)
    assert m["per_robot_median_ms"] == {"1": pytest.approx(2.0), "2": pytest.approx(2.0)}
    assert m["controllers"] == 1


def test_solve_time_decentralized_sums_over_robots() -> None:
    pos = np.zeros((3, 2, 2))
    pos[:, 1, 0] = 1.0
    st = np.array([[0.001, 0.002], [0.003, 0.001]])  # per sample: 3 ms, 4 ms
    m = compute_metrics(make_record(two_robots(), pos, solve_times=st,
                                    scheme="decentralized"))["solve_time"]
    assert m["total_s"] == pytest.approx(0.007)
    assert m["median_ms"] == pytest.approx(3.5)
    assert m["p99_ms"] == pytest.approx(3.99)
    assert m["max_ms"] == pytest.approx(4.0)
    assert m["per_robot_median_ms"] == {"1": pytest.approx(2.0), "2": pytest.approx(1.5)}
    assert m["controllers"] == 2


def test_contract_keys_and_json() -> None:
    sc = goal_scenario(np.zeros((2, 2)), diameters=(0.3, 0.3), ids=(7, 3))
    pos = np.zeros((3, 2, 2))
    pos[:, 1, 1] = 2.0
    rec = make_record(sc, pos, solver_failures=np.int64(2), completed=False,
                      extra={"missed_deadlines": np.int64(3), "steps": 99,
                             "arr": np.array([1.0, np.nan]), "mode": None})
    m = compute_metrics(rec)
    assert CONTRACT_KEYS <= m.keys()
    assert m["scenario"] == "unit" and m["scheme"] == "centralized"
    assert m["steps"] == 2 and m["planned_steps"] == 10 and m["horizon"] == 5
    assert m["solver_failures"] == 2 and m["completed"] is False
    assert set(m["rms_tracking_error"]) == {"7", "3"}
    assert m["ids"] == [7, 3]
    assert m["missed_deadlines"] == 3 and m["extra.steps"] == 99
    assert m["arr"] == [1.0, None] and m["mode"] is None
    text = json.dumps(m, allow_nan=False)
    assert json.loads(text) == m


def test_partial_record_k0() -> None:
    sc = two_robots()
    rec = RunRecord(scenario=sc, scheme="decentralized", t=np.array([0.0]),
                    states=np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]]),
                    inputs=np.empty(0), solve_times=np.empty((0, 2)))
    assert rec.inputs.shape == (0, 2, 2)
    m = compute_metrics(rec)
    assert m["steps"] == 0
    assert m["closed_loop_cost"] == 0.0
    assert m["min_distance"] == pytest.approx(1.0)
    assert m["input_bound_violations"] == 0
    assert m["solve_time"]["total_s"] == 0.0
    assert m["solve_time"]["median_ms"] is None and m["solve_time"]["max_ms"] is None
    assert m["solve_time"]["per_robot_median_ms"] == {"1": None, "2": None}
    json.dumps(m, allow_nan=False)


def test_non_finite_states_give_null() -> None:
    pos = np.array([[[0.0, 0.0], [1.0, 0.0]], [[np.nan, 0.0], [1.0, 0.0]]])
    m = compute_metrics(make_record(two_robots(), pos))
    assert m["min_distance"] is None and m["min_clearance"] is None
    assert m["rms_tracking_error"]["1"] is None
    json.dumps(m, allow_nan=False)


def test_record_shape_checks() -> None:
    sc = two_robots()
    with pytest.raises(ProblemError, match="states"):
        RunRecord(sc, "centralized", np.arange(3.0), np.zeros((3, 3, 3)), np.zeros((2, 2, 2)),
                  np.zeros((2, 1)))
    with pytest.raises(ProblemError, match="inputs"):
        RunRecord(sc, "centralized", np.arange(3.0), np.zeros((3, 2, 3)), np.zeros((3, 2, 2)),
                  np.zeros((2, 1)))
    with pytest.raises(ProblemError, match="solve_times"):
        RunRecord(sc, "centralized", np.arange(3.0), np.zeros((3, 2, 3)), np.zeros((2, 2, 2)),
                  np.zeros((2, 3)))


def test_trajectory_round_trip_without_pickle(tmp_path: Path) -> None:
    sc = goal_scenario(np.zeros((2, 2)), diameters=(0.3, 0.3), ids=(4, 9))
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(5, 2, 2))
    rec = make_record(sc, pos, inputs=rng.normal(size=(4, 2, 2)),
                      solve_times=rng.random((4, 2)))
    path = write_trajectory(tmp_path / "trajectory.npz", rec)
    with np.load(path, allow_pickle=False) as data:
        assert {"t", "states", "inputs", "ids", "solve_times"} <= set(data.files)
    loaded = load_trajectory(path)
    np.testing.assert_array_equal(loaded["t"], rec.t)
    np.testing.assert_array_equal(loaded["states"], rec.states)
    np.testing.assert_array_equal(loaded["inputs"], rec.inputs)
    np.testing.assert_array_equal(loaded["solve_times"], rec.solve_times)
    np.testing.assert_array_equal(loaded["ids"], [4, 9])
    assert np.issubdtype(loaded["ids"].dtype, np.integer)
    assert loaded["states"].shape == (5, 2, 3) and loaded["inputs"].shape == (4, 2, 2)


def test_write_metrics_atomic_and_strict(tmp_path: Path) -> None:
    path = write_metrics(tmp_path / "metrics.json", {"a": np.float64(1.5), "b": float("inf")})
    assert json.loads(path.read_text()) == {"a": 1.5, "b": None}
    assert os.listdir(tmp_path) == ["metrics.json"]


def _raising_plotter(record: RunRecord, out_dir: Path) -> list[Path]:
    raise RuntimeError("plotting broke")


def test_write_run_keeps_outputs_when_plotting_fails(tmp_path: Path) -> None:
    pos = np.zeros((3, 2, 2))
    pos[:, 1, 0] = 1.0
    rec = make_record(two_robots(), pos)
    out = tmp_path / "nested" / "run"
    with pytest.raises(RuntimeError, match="plotting broke"):
        write_run(out, rec, plotter=_raising_plotter)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["steps"] == 2
    assert load_trajectory(out / "trajectory.npz")["states"].shape == (3, 2, 3)


def test_write_run_without_plots(tmp_path: Path) -> None:
    pos = np.zeros((2, 2, 2))
    pos[:, 1, 0] = 1.0
    m = write_run(tmp_path, make_record(two_robots(), pos), plots=False,
                  plotter=_raising_plotter)
    assert sorted(os.listdir(tmp_path)) == ["metrics.json", "record.msgpack", "recording.mcap",
                                            "trajectory.npz"]
    assert json.loads((tmp_path / "metrics.json").read_text()) == m


def test_cpu_times_are_measured_reported_and_kept(tmp_path: Path) -> None:
    """A closed loop records each controller's thread CPU time beside its wall time; the
    metrics, the summary line, the trajectory file and the record file keep them, with
    the load average at the run's end."""
    from sqpmpc.io.reporting import describe_solve_time
    from sqpmpc.io.runlog import read_record, write_record
    from sqpmpc.problem.scenario_file import load_scenario
    from sqpmpc.sim.simulation import simulate

    sc = load_scenario("paper-s2").with_changes(t_end=2.0)
    record = simulate(sc, "decentralized")
    assert record.cpu_times is not None and record.cpu_times.shape == record.solve_times.shape
    assert np.all(record.cpu_times > 0) and np.all(np.isfinite(record.cpu_times))
    st = compute_metrics(record)["solve_time"]
    assert st["clock"] == "wall" and st["cpu"]["clock"] == "thread CPU time"
    assert st["cpu"]["total_s"] == pytest.approx(float(record.cpu_times.sum()))
    assert len(st["load_average"]) == 3 and st["cpus"] == os.cpu_count()
    line = describe_solve_time({"solve_time": st})
    assert line.startswith("controller CPU time per sample") and "wall time median" in line
    assert "load average" in line
    np.testing.assert_array_equal(
        load_trajectory(write_trajectory(tmp_path / "t.npz", record))["cpu_times"],
        record.cpu_times)
    again = read_record(write_record(tmp_path / "record.msgpack", record))
    np.testing.assert_array_equal(again.cpu_times, record.cpu_times)
