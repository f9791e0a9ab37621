"""The ``sqpmpc run`` command: contract outputs, user errors, interrupted runs."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sqpmpc.problem.scenario_file import load_scenario
from tests import HANG

CONTRACT_KEYS = {
    "scenario", "scheme", "steps", "sample_time", "horizon", "min_distance", "min_clearance",
    "collisions", "rms_tracking_error", "closed_loop_cost", "input_bound_violations",
    "solver_failures", "solve_time",
}


def run_cli(*args: str, timeout: float = HANG) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "sqpmpc", *args], capture_output=True,
                          text=True, timeout=timeout)


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_run_writes_the_contract_outputs(tmp_path: Path, scheme: str) -> None:
    scenario = tmp_path / "short.toml"
    scenario.write_text(load_scenario("paper-s1").with_changes(t_end=30.0).to_toml())
    out = tmp_path / "out"
    proc = run_cli("run", str(scenario), "--scheme", scheme, "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert CONTRACT_KEYS <= metrics.keys()
    assert metrics["scheme"] == scheme and metrics["steps"] == 30
    assert set(metrics["rms_tracking_error"]) == {"1", "2", "3", "4"}
    assert {"total_s", "median_ms", "p99_ms", "max_ms", "per_robot_median_ms"} <= set(
        metrics["solve_time"])
    traj = np.load(out / "trajectory.npz", allow_pickle=False)
    assert traj["t"].shape == (31,)
    assert traj["states"].shape == (31, 4, 3)
    assert traj["inputs"].shape == (30, 4, 2)
    np.testing.assert_array_equal(traj["ids"], [1, 2, 3, 4])
    for png in ("trajectories.png", "distances.png", "inputs.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


BAD = [
    ("unknown key", 'name = "x"\nt_end = 10.0\nsample_time = 1.0\nhorizon = 5\ncolour = 1\n',
     "colour"),
    ("missing file", None, "does-not-exist.toml"),
]


@pytest.mark.parametrize(("what", "text", "needle"), BAD, ids=[b[0] for b in BAD])
def test_bad_input_gives_one_clear_error_and_status_2(tmp_path: Path, what: str,
                                                      text: str | None, needle: str) -> None:
    path = tmp_path / ("bad.toml" if text is not None else "does-not-exist.toml")
    if text is not None:
        path.write_text(text)
    proc = run_cli("run", str(path), "--scheme", "centralized", "--out", str(tmp_path / "o"))
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0] and path.name in lines[0]
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(("args", "needles"), [
    (["--rule-param", "parking.gain=0.5"], ["parking", "gain", "0.5"]),
    (["--rule-param", "parking.gain=fast"], ["parking.gain", "fast"]),
    (["--without", "parkin"], ["--without", "parkin"]),
    (["--rules", "detour,nope"], ["--rules", "nope"]),
    (["--without", "detour", "--rule-param", "detour.hold=3"], ["--rule-param", "detour"]),
])
def test_bad_rule_options_are_refused_by_name(tmp_path: Path, args: list[str],
                                              needles: list[str]) -> None:
    proc = run_cli("run", "head-on", "--scheme", "centralized", *args,
                   "--out", str(tmp_path / "o"))
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and all(n in lines[0] for n in needles), lines
    assert not (tmp_path / "o").exists()


def test_rules_subcommand_lists_every_rule_and_safety_row() -> None:
    from sqpmpc.rules.registry import SAFETY_ROWS, rule_names

    proc = run_cli("rules")
    assert proc.returncode == 0
    lines = proc.stdout.splitlines()
    for name in [*rule_names(), *SAFETY_ROWS]:
        assert sum(line.split()[0] == name for line in lines if line.startswith("  ")) == 1


def test_overlapping_robots_are_refused(tmp_path: Path) -> None:
    sc = load_scenario("head-on")
    text = sc.to_toml().replace("initial_state = [3.0, 0.0,", "initial_state = [-2.9, 0.0,")
    path = tmp_path / "overlap.toml"
    path.write_text(text)
    proc = run_cli("run", str(path), "--scheme", "decentralized")
    assert proc.returncode == 2, proc.stderr
    assert "overlap" in proc.stderr and "Traceback" not in proc.stderr


def test_interrupted_run_keeps_what_it_had(tmp_path: Path) -> None:
    out = tmp_path / "out"
    long = tmp_path / "long.toml"  # 200,000 samples: far longer than the wait below
    long.write_text(load_scenario("paper-s2").with_changes(t_end=100000.0).to_toml())
    proc = subprocess.Popen(
        [sys.executable, "-m", "sqpmpc", "run", str(long), "--scheme", "decentralized",
         "--out", str(out), "--no-plots", "--status-every", "0.2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        # SIGINT at its default, as from a terminal: a background job of a shell (CI's,
        # perhaps) starts with it ignored, and an ignored Ctrl-C stays ignored
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    # the first status line says the loop runs (however long the imports took)
    line = proc.stderr.readline()
    while line and not line.startswith("paper-s2 decentralized: sample"):
        line = proc.stderr.readline()
    assert line, "the run ended without a status line"
    # one Ctrl-C is enough, also when it lands inside an OSQP solve (sqpmpc.cli.interrupts)
    proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=HANG)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
        pytest.fail(f"the Ctrl-C was lost: the run went on ({err[-500:]})")
    assert proc.returncode == 130, err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["completed"] is False
    assert 0 < metrics["steps"] < 200000
    traj = np.load(out / "trajectory.npz", allow_pickle=False)
    assert traj["states"].shape[0] == metrics["steps"] + 1


def _bad_cases() -> list[tuple[str, str, str]]:
    from tests.test_scenario import BAD_CASES

    return BAD_CASES


@pytest.mark.parametrize(("description", "text", "key"), _bad_cases(),
                         ids=[c[0] for c in _bad_cases()])
def test_every_kind_of_bad_file_exits_2_with_one_message(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], description: str, text: str,
        key: str) -> None:
    from sqpmpc.cli.main import main

    path = tmp_path / "bad-case.toml"
    path.write_text(text, encoding="utf-8")
    status = main(["run", str(path), "--scheme", "decentralized", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert status == 2, description
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and str(path) in lines[0] and key in lines[0], err
    assert not (tmp_path / "o").exists()


def test_version_is_printed() -> None:
    from sqpmpc import __version__

    proc = run_cli("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"sqpmpc {__version__}"
