"""One command line and one set of settings for every process (real processes, real Zenoh).

A distributed lockstep run with non-default controller options (flags or a
``--settings`` file) equals ``sqpmpc run`` with the same options; processes
started with other settings refuse to run together with one message and a
non-zero exit; errors name the flag the user typed; flags that do nothing are
refused; status lines written to a pipe hold no carriage return.
"""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from services.testing import REPO, free_ports, start_service, stop_processes
from sqpmpc.cli.main import main as sqpmpc_main
from tests import HANG
from tests.service_helpers import assert_lockstep_held

SCENARIO = "paper-s2"
OPTIONS = ["--collision-margin", "0.05", "--discretization", "exact"]
SETTINGS = 'collision_margin = 0.05\ndiscretization = "exact"\nt_end = 20.0\n'


def _run(*args: str, timeout: float = HANG) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO)


def _parse(capsys: pytest.CaptureFixture[str], module: str, *argv: str) -> tuple[int, str, str]:
    """``python -m MODULE ARGV`` up to its options' checks, in this process: the entry point
    the module's ``__main__`` calls (``sqpmpc``: :func:`sqpmpc.cli.main.main`, a service:
    its ``main``). Its status, stdout and stderr.

    What the process around it adds (one line on stderr, status 2, no traceback, for every
    module) is checked with real processes: ``test_bad_input_gives_one_message_and_status_2``
    (tests/test_services.py) and ``tests/test_cli.py``. A process costs ~2 s of CPU in
    imports alone, for each of the cases here."""
    if module == "sqpmpc":
        entry, args = sqpmpc_main, (list(argv),)
    else:
        entry, args = importlib.import_module(module).main, (list(argv), module)
    try:
        status = entry(*args)
    except SystemExit as exc:  # argparse and services.node.fail
        status = 0 if exc.code is None else exc.code
    out, err = capsys.readouterr()
    return status, out, err


@pytest.fixture(scope="module")
def sqpmpc_run(tmp_path_factory: pytest.TempPathFactory):
    """``sqpmpc run`` of the scenario with OPTIONS, once per scheme in a worker: the flags
    and the settings file are two ways to give the same options, compared to one run."""
    runs: dict[str, tuple[Path, subprocess.CompletedProcess[str]]] = {}

    def run(scheme: str) -> tuple[Path, subprocess.CompletedProcess[str]]:
        if scheme not in runs:
            ref = tmp_path_factory.mktemp(f"ref-{scheme}") / "ref"
            runs[scheme] = ref, _run("sqpmpc", "run", SCENARIO, "--scheme", scheme, *OPTIONS,
                                     "--t-end", "20", "--out", str(ref), "--no-plots",
                                     "--status-every", "0.01")
        return runs[scheme]

    return run


@pytest.mark.parametrize("scheme,source", [("decentralized", "flags"),
                                           ("centralized", "flags"),
                                           ("decentralized", "settings")])
def test_a_distributed_run_with_options_equals_sqpmpc_run(tmp_path: Path, sqpmpc_run,
                                                          scheme: str, source: str) -> None:
    settings = tmp_path / "run.toml"
    settings.write_text(SETTINGS)
    given = OPTIONS + ["--t-end", "20"] if source == "flags" else ["--settings", str(settings)]
    dist = tmp_path / "dist"
    ref, res = sqpmpc_run(scheme)
    assert res.returncode == 0, res.stderr
    assert "\r" not in res.stderr and f"{SCENARIO} {scheme}: sample " in res.stderr
    res = _run("sqpmpc", "launch", "--scenario", SCENARIO, "--scheme", scheme, *given,
               "--out", str(dist), "--no-plots", "--status-every", "0.01",
               "--timeout", str(HANG))  # the plant's lockstep wait: a hang guard only
    assert res.returncode == 0, res.stderr
    assert "plant: sample " in res.stderr and "\r" not in res.stderr + res.stdout
    if scheme == "decentralized":
        assert "summed over the 4 robots" in res.stdout and "per robot: median" in res.stdout
    else:
        assert "one central controller" in res.stdout
    a, b = np.load(ref / "trajectory.npz"), np.load(dist / "trajectory.npz")
    assert a["states"].shape == b["states"].shape == (41, 4, 3)
    assert np.max(np.abs(a["states"] - b["states"])) <= 1e-9
    m = json.loads((dist / "metrics.json").read_text())
    assert m["completed"] is True and m["collisions"] == 0
    assert_lockstep_held(m)  # no robot braked: its own input applied at every sample
    assert m["agreed_settings"]["collision_margin"] == "0.05"
    assert m["agreed_settings"]["discretization"] == "exact"
    # the options changed the run: the default settings give another trajectory
    default = json.loads((ref / "metrics.json").read_text())
    assert default["collision_margin"] == 0.05


@pytest.mark.parametrize("scheme,odd,needle", [
    ("decentralized", ["--collision-margin", "0.05"],
     "robot/2 runs with collision_margin 0.05 (the plant: 0.001)"),
    ("decentralized", ["--t-end", "30"], "robot/2 runs with t_end 30 (the plant: 20)"),
    ("centralized", ["--iteration", "sqp"], "central runs with iteration sqp (the plant: rti)"),
])
def test_a_process_with_other_settings_is_braked_and_named(tmp_path: Path, scheme: str,
                                                             odd: list[str],
                                                             needle: str) -> None:
    port, *ports = free_ports(3)
    plant_ep = f"tcp/127.0.0.1:{port}"
    common = ["--scenario", "head-on", "--run", "refuse", "--log-level", "WARNING"]
    plant = start_service("plant", [*common, "--t-end", "20", "--scheme", scheme, "--listen",
                                    plant_ep, "--out", str(tmp_path / "out"), "--no-plots"],
                          tmp_path / "logs")
    if scheme == "centralized":
        controllers = [start_service("central", [*common, "--t-end", "20", *odd, "--connect",
                                                 plant_ep], tmp_path / "logs")]
    else:
        controllers = [
            start_service("robot", ["--id", str(i), *common, "--insecure", "--listen",
                                    f"tcp/127.0.0.1:{p}", "--connect", plant_ep,
                                    *(odd if i == 2 else ["--t-end", "20"])],
                          tmp_path / "logs", name=f"robot-{i}")
            for i, p in zip((1, 2), ports, strict=True)]
    try:
        assert plant.wait(HANG) == 2, plant.output()
        odd_one = controllers[-1]
        assert odd_one.wait(HANG) == 2, odd_one.output()
        if scheme == "decentralized":
            assert controllers[0].wait(HANG) == 0, controllers[0].output()
    finally:
        stop_processes([plant, *controllers])
    errors = [ln for ln in plant.output().splitlines() if " ERROR " in ln]
    assert len(errors) == 1 and needle in errors[0], plant.output()
    assert "--settings" in errors[0]
    assert "Traceback" not in plant.output() + odd_one.output()
    assert "the plant runs with other" in odd_one.output() or \
        "the plant runs with another scenario" in odd_one.output()
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    # the run went on to its end, the odd controller's robots braked: never applied
    assert m["completed"] is True and m["refused"] and needle in m["refused"]
    braked = [2] if scheme == "decentralized" else [1, 2]
    assert all(m["missed_deadlines_by_robot"][str(i)] == m["steps"] for i in braked)
    assert m["collisions"] == 0


def _one_error(res: tuple[int, str, str], prog: str, *needles: str) -> None:
    status, _, stderr = res
    assert status == 2, stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), stderr
    assert all(n in lines[0] for n in needles), lines[0]


BAD = [
    (["run", "head-on", "--scheme", "decentralized", "--message-drop", "2"],
     ["--message-drop: expected a probability in [0, 1], got 2"]),
    (["run", "head-on", "--scheme", "decentralized", "--collision-margin", "-0.1"],
     ["--collision-margin: expected a number >= 0, got -0.1"]),
    (["run", "head-on", "--scheme", "decentralized", "--t-end", "0.3"], ["--t-end: ", "0.3"]),
    (["run", "head-on", "--scheme", "decentralized", "--horizon", "0"], ["--horizon: "]),
    (["run", "head-on", "--scheme", "decentralized", "--rules", "nope"], ["--rules", "nope"]),
    (["run", "head-on", "--scheme", "centralized", "--decentralized-mode", "paper"],
     ["--decentralized-mode does nothing with --scheme centralized"]),
    (["run", "head-on", "--scheme", "centralized", "--message-drop", "0.1"],
     ["--message-drop does nothing with --scheme centralized"]),
    (["launch", "--scenario", "head-on", "--scheme", "centralized", "--robots-per-process",
      "2"], ["--robots-per-process does nothing with --scheme centralized"]),
    (["launch", "--scenario", "head-on", "--scheme", "centralized", "--all-plans"],
     ["--all-plans does nothing with --scheme centralized"]),
    (["launch", "--scenario", "head-on", "--scheme", "decentralized", "--all-plans"],
     ["--all-plans does nothing without neighbour slots"]),
    (["launch", "--scenario", "head-on", "--scheme", "decentralized", "--insecure",
      "--credentials", "x"], ["--credentials", "--insecure"]),
    (["launch", "--scenario", "head-on", "--scheme", "decentralized", "--robots-per-process",
      "0"], ["--robots-per-process: expected an integer >= 1, got 0"]),
    (["plant", "--scenario", "head-on", "--timed-start"], ["--timed-start"]),
    (["plant", "--scenario", "head-on", "--scheme", "centralized", "--decentralized-mode",
      "paper"], ["--decentralized-mode does nothing"]),
    (["robot", "--id", "1", "--scenario", "head-on", "--timeout", "0"],
     ["--timeout: expected a number > 0, got 0"]),
    (["robot", "--id", "1", "--scenario", "head-on", "--mode", "paper"],
     ["unrecognized arguments: --mode paper"]),
    (["central", "--scenario", "head-on", "--sample-time", "nan"], ["--sample-time: "]),
]


@pytest.mark.parametrize("argv,needles", BAD, ids=[" ".join(b[0][:1] + b[0][-2:]) for b in BAD])
def test_errors_name_the_flag_and_no_op_flags_are_refused(capsys: pytest.CaptureFixture[str],
                                                         argv: list[str],
                                                         needles: list[str]) -> None:
    _one_error(_parse(capsys, "sqpmpc", *argv), f"sqpmpc {argv[0]}", *needles)


@pytest.mark.parametrize("text,needles", [
    ("colour = 1\n", ["unknown key 'colour'"]),
    ("collision_margin = -1\n", ["collision_margin: expected a number >= 0, got -1"]),
    ('discretization = "rk5"\n', ["discretization: expected one of"]),
    ("rules = [\"nope\"]\n", ["rules in", "nope"]),
    ("t_end = 0.3\n", ["t_end in", "0.3"]),
    ("collision_margin = \n", ["not valid TOML"]),
])
def test_a_bad_settings_file_is_refused_naming_the_key_and_the_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str,
        needles: list[str]) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    for argv, prog in ((["sqpmpc", "run", "head-on", "--scheme", "decentralized"], "sqpmpc run"),
                       (["services.robot", "--id", "1", "--scenario", "head-on"],
                        "services.robot")):
        _one_error(_parse(capsys, *argv, "--settings", str(path)), prog, "bad.toml", *needles)


def test_every_command_has_help_and_version(capsys: pytest.CaptureFixture[str]) -> None:
    for name in ("launch", "plant", "robot", "central", "router"):
        status, out, err = _parse(capsys, "sqpmpc", name, "--help")
        assert status == 0 and out.startswith(f"usage: sqpmpc {name} "), (status, out, err)
        if name != "router":
            assert "--settings FILE.toml" in out and "--t-end" in out
        if name in ("launch", "robot", "central"):
            assert "--collision-margin" in out and "--discretization" in out
    for name in ("launch", "plant"):
        status, out, err = _parse(capsys, f"services.{name}", "--version")
        assert status == 0 and out.startswith(f"services.{name} "), (status, out, err)
