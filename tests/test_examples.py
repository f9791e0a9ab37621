"""Every script in examples/ runs (short) and prints its result."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import sqpmpc
from sqpmpc.cli.main import main as cli_main
from tests import HANG

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


def _run(script: str, *args: str) -> str:
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    done = subprocess.run([sys.executable, str(EXAMPLES / script), *args], capture_output=True,
                          text=True, env=env, cwd=ROOT, timeout=HANG)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    return done.stdout


def _clearance(text: str) -> float:
    return float(re.search(r"min clearance (-?[0-9.]+) m", text).group(1))


def test_every_example_is_tested() -> None:
    tested = {"own_loop.py", "decentralized_fleet.py", "read_run.py", "record_own_loop.py"}
    assert {p.name for p in EXAMPLES.glob("*.py")} == tested


def test_own_loop() -> None:
    out = _run("own_loop.py", "--steps", "8")
    assert re.search(r"^8 steps of head-on-in-code: min clearance", out, re.M), out
    assert _clearance(out) >= 0.0
    assert "fallbacks 0" in out


@pytest.mark.parametrize("drop", ["0", "0.5"])
def test_decentralized_fleet(drop: str) -> None:
    out = _run("decentralized_fleet.py", "--steps", "6", "--drop", drop)
    assert re.search(r"^6 steps of crossing-4, 4 controllers: min clearance", out, re.M), out
    assert _clearance(out) >= 0.0
    lost = int(re.search(r"plans lost (\d+)", out).group(1))
    assert (lost == 0) == (drop == "0")


def test_read_run(tmp_path: Path) -> None:
    sc = sqpmpc.load_scenario("head-on").with_changes(t_end=3.0)
    metrics = sqpmpc.write_run(tmp_path, sqpmpc.simulate(sc, "decentralized"), plots=False)
    (tmp_path / "clearance.png").write_bytes(b"the run's own plot")
    out = _run("read_run.py", str(tmp_path))
    assert (tmp_path / "clearance.png").read_bytes() == b"the run's own plot"  # left alone
    assert out.startswith("head-on / decentralized: 6 steps of 0.5 s, horizon")
    assert f"min clearance {metrics['min_clearance']:.4f} m" in out
    assert len(re.findall(r"^  robot \d+: path [0-9.]+ m, RMS tracking error", out, re.M)) == 2
    png = tmp_path / "read_run_clearance.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_record_own_loop(tmp_path: Path) -> None:
    out = tmp_path / "mine"
    text = _run("record_own_loop.py", "--steps", "8", "--out", str(out))
    assert text.startswith("crossing-4 / decentralized: 8 samples of "), text
    assert "arrival: " in text and f"wrote {out}" in text
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["steps"] == 8 and metrics["collisions"] == 0
    assert set(metrics["arrived"]) == {"1", "2", "3", "4"}
    assert metrics["solve_time"]["controllers"] == 4
    for name in ("trajectory.npz", "record.msgpack", "recording.mcap", "trajectories.png"):
        assert (out / name).is_file(), name
    # the folder reads back like any run's, and a second write is refused
    assert cli_main(["metrics", str(out)]) == 0
    assert json.loads((out / "metrics.json").read_text())["steps"] == 8
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    again = subprocess.run([sys.executable, str(EXAMPLES / "record_own_loop.py"), "--steps", "2",
                            "--out", str(out)], capture_output=True, text=True, env=env,
                           cwd=ROOT, timeout=HANG)
    assert again.returncode == 2 and "not empty" in again.stderr
    assert "Traceback" not in again.stderr
