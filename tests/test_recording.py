"""recording.mcap, read back with the ``mcap`` reader (independent of the writer).

Each run's recording must hold exactly one pose message per robot per sample,
equal to ``trajectory.npz``, and the plans of ``trajectory.npz``'s horizons;
for ``sqpmpc run`` and for a distributed lockstep run's plant.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from sqpmpc.cli.main import main
from sqpmpc.io.files import load_trajectory
from sqpmpc.io.recording import POSE_TOPIC, write_recording
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.record import RunRecord
from tests import HANG
from tests.scenarios import circle_scenario

REPO = Path(__file__).resolve().parent.parent


def read_mcap(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """Every message per topic, in log-time order: ``(log_time ns, decoded)``."""
    out: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    factory = DecoderFactory()
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if channel.message_encoding == "json":
                decoded = json.loads(message.data)
            else:
                assert channel.message_encoding == "protobuf"
                assert schema is not None and schema.name.startswith("foxglove.")
                decoded = factory.decoder_for("protobuf", schema)(message.data)
            out[channel.topic].append((message.log_time, decoded))
    return out


def _yaw(q: Any) -> float:
    return 2.0 * math.atan2(q.z, q.w)


def check_recording(run_dir: Path, missing_plans: int = 0) -> dict[str, list[tuple[int, Any]]]:
    """Poses and plans of ``recording.mcap`` against ``trajectory.npz``.

    ``missing_plans``: how many plans per robot may be absent (a distributed
    plant records the plans it received; it never waits for them).
    """
    traj = load_trajectory(run_dir / "trajectory.npz")
    topics = read_mcap(run_dir / "recording.mcap")
    t, states, ids = traj["t"], traj["states"], traj["ids"]
    K = t.size - 1
    for j, rid in enumerate(ids):
        poses = topics[POSE_TOPIC.format(id=int(rid))]
        assert len(poses) == K + 1  # exactly one message per robot per sample
        for k, (log_time, msg) in enumerate(poses):
            assert log_time == round(t[k] * 1e9)
            assert msg.frame_id == "world"
            assert msg.timestamp.seconds * 10**9 + msg.timestamp.nanos == log_time
            p = msg.pose.position
            assert (p.x, p.y) == (states[k, j, 0], states[k, j, 1])
            dpsi = _yaw(msg.pose.orientation) - states[k, j, 2]
            assert abs(math.remainder(dpsi, 2 * math.pi)) < 1e-9
        plans = topics[f"/robots/{int(rid)}/horizon"]
        # a plan at every sample where an input was computed (NaN in the npz: not received)
        received = np.flatnonzero(np.isfinite(traj["horizons"][:, j, 0, 0]))
        assert K - missing_plans <= len(plans) == received.size
        for k, (log_time, msg) in zip(received, plans, strict=True):
            assert log_time == round(t[k] * 1e9)
            xy = np.array([[q.position.x, q.position.y] for q in msg.poses])
            np.testing.assert_allclose(xy, traj["horizons"][k, j, :, :2], atol=1e-5)
            # stage 0 of the plan computed at t_k is the state measured at t_k
            np.testing.assert_allclose(xy[0], states[k, j, :2], atol=1e-9)
    scene = topics["/scene"]
    assert len(scene) == K + 1
    names = {e.id for e in scene[0][1].entities}
    assert {f"robot_{int(i)}" for i in ids} <= names
    return topics


@pytest.mark.parametrize("scheme", ["decentralized", "centralized"])
def test_sqpmpc_run_writes_the_recording(tmp_path: Path, scheme: str) -> None:
    scenario = tmp_path / "s2.toml"
    scenario.write_text(load_scenario("paper-s2").with_changes(t_end=10.0).to_toml())
    out = tmp_path / "run"
    assert main(["run", str(scenario), "--scheme", scheme, "--out", str(out), "--no-plots",
                 "--quiet"]) == 0
    topics = check_recording(out)
    metrics = json.loads((out / "metrics.json").read_text())
    clearance = [m["min"] for _, m in topics["/clearance"]]
    assert min(clearance) == pytest.approx(metrics["min_clearance"], abs=1e-9)
    assert len(topics["/solve_time"]) == metrics["steps"] == 20
    assert all(m["budget_ms"] == 500.0 for _, m in topics["/solve_time"])


def test_distributed_lockstep_plant_writes_the_recording(tmp_path: Path) -> None:
    out = tmp_path / "dist"
    res = subprocess.run([sys.executable, "-m", "services.launch", "--scenario", "paper-s2",
                          "--scheme", "decentralized", "--t-end", "5", "--out", str(out),
                          "--no-plots"], capture_output=True, text=True, timeout=HANG, cwd=REPO)
    assert res.returncode == 0, res.stderr
    check_recording(out, missing_plans=1)


def test_a_partial_record_without_plans(tmp_path: Path) -> None:
    sc = circle_scenario((0.3, 0.4, 0.5))
    k = 3
    t = sc.sample_time * np.arange(k + 1)
    states = np.repeat(sc.initial_states()[None], k + 1, axis=0)
    record = RunRecord(sc, "decentralized", t, states, np.zeros((k, 3, 2)),
                       np.full((k, 3), 1e-3))
    path = write_recording(tmp_path / "r.mcap", record)
    topics = read_mcap(path)
    assert not any(topic.endswith("/horizon") for topic in topics)
    for rid in sc.ids:
        assert len(topics[POSE_TOPIC.format(id=int(rid))]) == k + 1
    st = topics["/solve_time"]
    assert len(st) == k and st[0][1]["total_ms"] == pytest.approx(3.0)
    assert not list(tmp_path.glob(".*tmp"))  # written through a temporary file
