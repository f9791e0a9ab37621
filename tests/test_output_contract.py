"""One output contract for every runner, refused goals, and progress on the long waits.

- ``sqpmpc run``, ``services.launch`` and ``services.plant`` refuse a non-empty ``--out``
  unless ``--overwrite`` (exit 2, one line, the folder untouched) and a goal the static
  map makes unreachable (exit 2, naming the robot), before anything runs.
- ``sqpmpc run`` prints its summary before it writes the plots.
- The kernels' and the launcher's progress lines.
"""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

import sqpmpc
from sqpmpc.cli.main import main as sqpmpc_main
from sqpmpc.problem.goals import unreachable_goals

ROOT = Path(__file__).resolve().parent.parent

WALLED = """name = "walled"
t_end = 4.0
sample_time = 0.5
horizon = 8
[weights]
Q = [1.0, 1.0]
R = [0.5, 0.5]
[bounds]
v = [-0.6, 0.6]
omega = [-0.785, 0.785]
[[robots]]
id = 1
initial_state = [-3.0, 0.0, 0.0]
diameter = 0.3
reference = { type = "point", position = [3.0, 0.0] }
[[robots]]
id = 7
initial_state = [-3.0, 2.0, 0.0]
diameter = 0.3
reference = { type = "point", position = [GOAL] }
[[obstacles]]
points = [[1.5, -0.5], [2.5, -0.5], [2.5, 0.5], [1.5, 0.5]]
[[obstacles]]
position = [0.0, 3.0]
diameter = 0.6
"""


def _walled(tmp_path: Path, goal: str) -> Path:
    path = tmp_path / "walled.toml"
    path.write_text(WALLED.replace("GOAL", goal))
    return path


def _service(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True,
                          text=True, cwd=ROOT)


@pytest.mark.parametrize(("goal", "why"), [("2.0, 0.0", "inside polygons[0]"),
                                           ("2.6, 0.0", "from the boundary of polygons[0]"),
                                           ("0.0, 2.7", "from the centre of obstacles[0]")])
def test_an_unreachable_goal_is_named_by_robot(tmp_path, goal, why):
    scenario = sqpmpc.load_scenario(_walled(tmp_path, goal))
    found = unreachable_goals(scenario)
    assert len(found) == 1 and found[0].startswith("robot id 7 (robots[1])") and why in found[0]


def test_the_builtin_scenarios_have_reachable_goals():
    for name in sqpmpc.builtin_scenario_names():
        assert unreachable_goals(sqpmpc.load_scenario(name)) == [], name


def test_sqpmpc_run_refuses_an_unreachable_goal_before_the_run(tmp_path, capsys):
    out = tmp_path / "out"
    assert sqpmpc_main(["run", str(_walled(tmp_path, "2.0, 0.0")), "--scheme", "centralized",
                        "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "robot id 7" in err[0] and "inside polygons[0]" in err[0]
    assert not out.exists()


def test_launch_refuses_an_unreachable_goal_and_a_non_empty_out(tmp_path):
    out = tmp_path / "out"
    res = _service("services.launch", "--scenario", str(_walled(tmp_path, "2.0, 0.0")),
                   "--scheme", "decentralized", "--out", str(out))
    assert res.returncode == 2 and "robot id 7" in res.stderr, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and not out.exists()
    out.mkdir()
    (out / "metrics.json").write_text("{}")
    res = _service("services.launch", "--scenario", "paper-s2", "--scheme", "decentralized",
                   "--out", str(out))
    assert res.returncode == 2 and "--overwrite" in res.stderr, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
    assert (out / "metrics.json").read_text() == "{}"  # untouched


def test_the_plant_refuses_a_non_empty_out(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    res = _service("services.plant", "--scenario", "paper-s2", "--out", str(out))
    assert res.returncode == 2 and "not empty" in res.stderr and "--overwrite" in res.stderr
    assert (out / "notes.txt").read_text() == "mine"


def test_sqpmpc_run_prints_the_summary_before_writing_the_plots(tmp_path, capsys):
    out = tmp_path / "out"
    assert sqpmpc_main(["run", "head-on", "--scheme", "centralized", "--t-end", "1",
                        "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert text.index("head-on / centralized") < text.index("plots: trajectories.png (1/7") \
        < text.index("plots: paths_by_robot.png (7/7") < text.index(f"wrote {out}")
    assert (out / "trajectories.png").exists()


def test_the_kernels_report_each_compilation_every_few_seconds(capsys, monkeypatch):
    from sqpmpc.kernels import __main__ as kernels_main

    monkeypatch.setattr(kernels_main, "EVERY", 0.0)
    lines = kernels_main.CompileLines()

    def event(name: str) -> SimpleNamespace:
        return SimpleNamespace(data={"dispatcher": SimpleNamespace(
            py_func=SimpleNamespace(__qualname__=name))})

    for name in ("euler_step", "polygon_rows"):
        lines.on_start(event(name))
        lines.on_end(event(name))
    out = capsys.readouterr().out.splitlines()
    assert [line.split("(last: ")[1].split(")")[0] for line in out] == ["euler_step",
                                                                         "polygon_rows"]
    assert out[1].strip().startswith("2 kernels compiled")


def test_the_launcher_says_it_is_starting_until_the_first_sample(tmp_path, caplog,
                                                                 monkeypatch):
    from services import launch

    monkeypatch.setattr(launch, "START_EVERY", 0.0)
    record = tmp_path / "record.msgpack"
    with caplog.at_level(logging.INFO, logger="services.launch"):
        progress = launch.StartProgress(record, 5)
        progress.tick()
        progress.tick()
        record.write_bytes(b"x")
        progress.tick()
        progress.tick()
    messages = [r.getMessage() for r in caplog.records]
    assert messages[0].startswith("started 5 processes")
    assert sum(m.startswith("still starting") for m in messages) == 2
    assert messages[-1].startswith("the run started after")


def test_a_ros2_fleet_log_becomes_the_run_folder_of_every_runner(tmp_path, capsys):
    """``poses.json`` (exact segments in wall time) sampled every Ts from the epoch: the
    folder reads back with ``sqpmpc metrics`` like any run's."""
    import json

    import numpy as np

    from services.ros2.record import fleet_record
    from sqpmpc.io.files import write_run

    scenario = sqpmpc.load_scenario("head-on")  # two robots, Ts 0.5 s
    epoch = 1000.0
    x0 = scenario.initial_states()
    robots = {}
    for j, rid in enumerate(scenario.ids):
        v = 0.2 if j == 0 else -0.2  # towards each other along x, from 0.25 s before t = 0
        start = [epoch - 0.25, *x0[j], 0.0, 0.0]
        moving = [epoch + 0.1, *(x0[j] + [0.0, 0.0, 0.0]), abs(v), 0.0]
        robots[str(int(rid))] = {"diameter": 0.3, "segments": [start, moving]}
    data = {"epoch": epoch, "start": epoch - 0.25, "end": epoch + 2.2, "robots": robots}
    record = fleet_record(data, scenario, t_end=3.0)
    assert record.t.tolist() == [0.0, 0.5, 1.0, 1.5, 2.0]  # the log ends at 2.2 s
    assert not record.completed  # t_end 3 s was not reached
    assert np.allclose(record.states[0], x0)
    heading = x0[:, 2]
    travelled = np.hypot(*(record.states[4, :, :2] - x0[:, :2]).T)
    assert np.allclose(travelled, 0.2 * (2.0 - 0.1)) and np.allclose(
        record.states[4, :, 2], heading)
    assert np.allclose(record.inputs[0], 0.0) and np.allclose(record.inputs[1:, :, 0], 0.2)
    out = tmp_path / "run"
    write_run(out, record, plots=False)
    assert sqpmpc_main(["metrics", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["steps"] == 4 and metrics["completed"] is False
    text = capsys.readouterr().out
    assert "head-on" in text
    assert "controller time per sample: not measured here (each controller" in text
