"""Honest results: arrivals in metrics and summaries, --fail-on-miss, --out refused before
the run, one number format, summaries that fit a screen at 64 robots, robots named by id,
``sqpmpc metrics`` on an in-process run's folder."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

import sqpmpc
from sqpmpc.cli.main import main
from sqpmpc.errors import ScenarioError
from sqpmpc.io.reporting import id_ranges, missed_goal, quantity, summarize
from sqpmpc.problem.scenario_file import load_scenario

ARRIVAL_KEYS = {"final_position_error", "max_final_position_error", "arrived", "all_arrived"}


def test_quantity_has_three_significant_digits_and_a_unit() -> None:
    assert quantity(0.0009974591290105583, "m") == "0.000997 m"
    assert quantity(1234.5, "ms") == "1.23e+03 ms"
    assert quantity(None, "m") == "n/a"
    assert id_ranges([7, 1, 2, 3, 9, 10]) == "1-3, 7, 9-10"


def test_a_run_that_arrives_exits_0_even_with_fail_on_miss(tmp_path: Path, capsys) -> None:
    out = tmp_path / "run"
    assert main(["run", "head-on", "--scheme", "centralized", "--out", str(out),
                 "--no-plots", "--fail-on-miss"]) == 0
    text = capsys.readouterr().out
    metrics = json.loads((out / "metrics.json").read_text())
    assert ARRIVAL_KEYS <= metrics.keys()
    assert metrics["all_arrived"] is True and metrics["arrived"] == {"1": True, "2": True}
    assert metrics["max_final_position_error"] <= 0.05
    assert "arrival: 2/2 robots within 0.05 m" in text


def test_a_robot_that_does_not_arrive_is_named_and_fails_the_run(tmp_path: Path,
                                                                 capsys) -> None:
    out = tmp_path / "run"
    status = main(["run", "head-on", "--scheme", "decentralized", "--t-end", "3",
                   "--out", str(out), "--no-plots", "--fail-on-miss"])
    captured = capsys.readouterr()
    assert status == 4
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["all_arrived"] is False and metrics["arrived"] == {"1": False, "2": False}
    assert "0/2 robots" in captured.out and "NOT arrived: robots 1-2" in captured.out
    assert "did not arrive" in captured.err and "Traceback" not in captured.err
    # without the flag the same run is a success (it completed)
    assert main(["run", "head-on", "--scheme", "decentralized", "--t-end", "3",
                 "--out", str(tmp_path / "again"), "--no-plots", "--quiet"]) == 0


def test_out_is_refused_before_the_run_unless_overwrite(tmp_path: Path, capsys) -> None:
    afile = tmp_path / "afile"
    afile.write_text("keep me")
    assert main(["run", "head-on", "--scheme", "centralized", "--out", str(afile)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is a file" in err and afile.read_text() == "keep me"
    old = tmp_path / "old"
    old.mkdir()
    (old / "distances.png").write_bytes(b"old plot")
    (old / "notes.txt").write_text("mine")
    assert main(["run", "head-on", "--scheme", "centralized", "--out", str(old)]) == 2
    err = capsys.readouterr().err
    assert "not empty" in err and "--overwrite" in err
    assert not (old / "metrics.json").exists()  # refused before the run: nothing written
    assert main(["run", "head-on", "--scheme", "centralized", "--t-end", "2", "--out",
                 str(old), "--no-plots", "--overwrite"]) == 0
    assert not (old / "distances.png").exists()  # no old plot beside the new metrics
    assert (old / "notes.txt").read_text() == "mine"
    assert json.loads((old / "metrics.json").read_text())["steps"] == 4


def test_metrics_command_reads_an_in_process_run(tmp_path: Path, capsys) -> None:
    out = tmp_path / "run"
    assert main(["run", "head-on", "--scheme", "decentralized", "--t-end", "4", "--out",
                 str(out), "--no-plots", "--quiet"]) == 0
    first = json.loads((out / "metrics.json").read_text())
    (out / "metrics.json").unlink()
    capsys.readouterr()
    assert main(["metrics", str(out)]) == 0
    again = json.loads((out / "metrics.json").read_text())
    for key in ("steps", "completed", "collisions", "solver_failures", "arrived",
                "final_position_error", "rms_tracking_error", "min_clearance", "solve_time"):
        assert again[key] == first[key], key
    assert "arrival: 0/2" in capsys.readouterr().out
    assert main(["metrics", str(out), "--fail-on-miss"]) == 4


def test_the_summary_of_64_robots_fits_one_screen() -> None:
    scenario = load_scenario("swap-64")
    recorder = sqpmpc.RunRecorder(scenario, "decentralized")
    recorder.append(0.0, scenario.initial_states())  # the initial states only: none arrived
    metrics = sqpmpc.compute_metrics(recorder.record())
    text = summarize(metrics)
    lines = text.splitlines()
    assert len(lines) <= 6 and max(len(line) for line in lines) <= 240, text
    assert "0/64 robots" in text and "NOT arrived: robots 1-64" in text
    assert text.count("id ") <= 12  # the worst few, not one entry per robot
    # every number has at most three significant digits
    for number in re.findall(r"\d+\.\d+(?:e[-+]\d+)?", text):
        digits = re.sub(r"e.*", "", number).replace(".", "").lstrip("0")
        assert len(digits) <= 3, number


def test_missed_goal_names_collisions_first() -> None:
    ok = {"completed": True, "collisions": 0, "arrived": {"1": True}}
    assert missed_goal(ok) is None
    assert "did not arrive" in missed_goal({**ok, "arrived": {"1": True, "2": False}})
    assert "collision" in missed_goal({**ok, "intersample_collisions": 2})
    assert "did not complete" in missed_goal({**ok, "completed": False})


def test_scenario_errors_name_the_robot_by_id() -> None:
    text = load_scenario("head-on").to_toml()
    bad = text.replace("diameter = 0.3", "diameter = -0.3", 2).replace(
        "diameter = -0.3", "diameter = 0.3", 1)  # only the second robot's diameter
    with pytest.raises(ScenarioError) as info:
        sqpmpc.parse_scenario(__import__("tomllib").loads(bad), "bad.toml")
    assert info.value.key.startswith("robots[1]")
    assert "robot id 2 (the 2nd [[robots]] table)" in str(info.value)


def test_a_summary_of_a_distributed_run_says_the_deadlines() -> None:
    scenario = load_scenario("head-on")
    recorder = sqpmpc.RunRecorder(scenario)
    recorder.append(0.0, scenario.initial_states(), np.zeros((2, 2)), solve_time=0.001)
    recorder.append(0.5, scenario.initial_states())
    recorder.extra.update({"distributed": True, "mode": "lockstep", "missed_deadlines": 3,
                           "missed_deadlines_by_robot": {"1": 3, "2": 0},
                           "invalid_messages": 0, "sample_loop_wall_s": 1.23456})
    text = summarize(sqpmpc.compute_metrics(recorder.record()))
    assert "(lockstep)" in text and "missed deadlines 3 (most: id 1: 3)" in text
    assert "1.23 s wall" in text


def test_a_recorded_loop_has_the_metrics_of_the_same_simulated_run() -> None:
    scenario = load_scenario("head-on").with_changes(t_end=4.0)
    simulated = sqpmpc.simulate(scenario, "decentralized")
    recorder = sqpmpc.RunRecorder(scenario, "decentralized")
    for k in range(simulated.k):
        recorder.append(simulated.t[k], simulated.states[k], simulated.inputs[k],
                        solve_time=simulated.solve_times[k], cpu_time=simulated.cpu_times[k])
    recorder.append(simulated.t[-1], simulated.states[-1])
    mine, theirs = (sqpmpc.compute_metrics(r) for r in (recorder.record(), simulated))
    for m in (mine, theirs):  # the machine's load when each record was taken
        assert len(m["solve_time"].pop("load_average")) == 3
    for key in ("steps", "completed", "min_clearance", "collisions", "rms_tracking_error",
                "closed_loop_cost", "final_position_error", "arrived", "solve_time"):
        assert mine[key] == theirs[key], key


def test_the_recorder_refuses_bad_samples_by_number() -> None:
    scenario = load_scenario("head-on")
    recorder = sqpmpc.RunRecorder(scenario)
    x = scenario.initial_states()
    recorder.append(0.0, x, np.zeros((2, 2)))
    with pytest.raises(sqpmpc.ProblemError, match=r"sample 1: inputs must be finite"):
        recorder.append(0.5, x, np.zeros((3, 2)))
    with pytest.raises(sqpmpc.ProblemError, match=r"sample 1: t = 0.0"):
        recorder.append(0.0, x, np.zeros((2, 2)))
    with pytest.raises(sqpmpc.ProblemError, match=r"sample 1: states"):
        recorder.append(0.5, np.full((2, 3), np.nan), np.zeros((2, 2)))
    recorder.append(0.5, x)  # the final states
    with pytest.raises(sqpmpc.ProblemError, match="final states were already appended"):
        recorder.append(1.0, x, np.zeros((2, 2)))
    record = recorder.record()
    assert record.k == 1 and record.inputs.shape == (1, 2, 2) and not record.completed
    with pytest.raises(sqpmpc.ProblemError, match="nothing recorded"):
        sqpmpc.RunRecorder(scenario).record()
