"""The live viewer beside a real lockstep run, read by a real Foxglove WebSocket client.

The viewer listens on a loopback Zenoh endpoint, the launcher's plant connects
to it (``services.launch --connect``), and a ``websockets`` client speaking
Foxglove's WebSocket protocol (subprotocol ``foxglove.sdk.v1`` of foxglove-sdk
0.30) subscribes to a robot's pose channel and decodes what
it receives with the protobuf schema the server advertised.
"""

from __future__ import annotations

import base64
import json
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory
from websockets.sync.client import ClientConnection, connect

from services.testing import (
    REPO,
    ServiceProcess,
    free_ports,
    start_service,
    stop_processes,
)
from sqpmpc.io.recording import POSE_TOPIC

pytestmark = pytest.mark.timeout(120)

SUBPROTOCOL = "foxglove.sdk.v1"


def _wait_serving(viewer: ServiceProcess, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while "viewer: open ws://" not in viewer.output():
        assert viewer.proc.poll() is None and time.monotonic() < deadline, viewer.output()
        time.sleep(0.1)


def _advertised(ws: ClientConnection, topics: set[str]) -> dict[str, dict]:
    """Channels advertised by the server, by topic, until every one of ``topics`` is seen."""
    channels: dict[str, dict] = {}
    while not topics <= set(channels):
        msg = ws.recv(timeout=30.0)
        if isinstance(msg, str):
            data = json.loads(msg)
            if data.get("op") == "advertise":
                channels.update({c["topic"]: c for c in data["channels"]})
    return channels


def test_viewer_serves_the_poses_of_a_lockstep_run(tmp_path: Path) -> None:
    run = "viewer-test"
    zport, wsport = free_ports(2)
    endpoint = f"tls/127.0.0.1:{zport}"
    credentials = tmp_path / "credentials"  # the run's, shared by the viewer and the launcher
    made = subprocess.run([sys.executable, "-m", "sqpmpc", "credentials", "--scenario",
                           "paper-s2", "--run", run, "--out", str(credentials)],
                          capture_output=True, text=True, timeout=60, cwd=REPO)
    assert made.returncode == 0, made.stderr
    viewer = start_service("viewer", ["--scenario", "paper-s2", "--t-end", "5", "--run", run,
                                      "--listen", endpoint, "--port", str(wsport),
                                      "--credentials", str(credentials),
                                      "--exit-on-done"], tmp_path / "logs")
    procs = [viewer]
    try:
        _wait_serving(viewer)
        with connect(f"ws://127.0.0.1:{wsport}", subprotocols=[SUBPROTOCOL],
                     max_queue=None) as ws:  # buffer everything while the run runs
            poses, clearances, out = _watch(ws, run, endpoint, credentials, tmp_path)
        assert viewer.wait(30) == 0, viewer.output()
    finally:
        stop_processes(procs)
    states = np.load(out / "trajectory.npz")["states"]
    # what the client received is robot 1's trajectory, sample by sample (the plant
    # publishes the states of samples 0..K-1)
    np.testing.assert_array_equal(np.array(poses), states[:-1, 0, :2])
    assert len(clearances) == 10 and min(clearances) > 0.0
    # every robot's plan and input of every sample reached the viewer (the launcher connects
    # every process to it)
    assert "10 samples shown (10 with every plan and input" in viewer.output()


def _watch(ws: ClientConnection, run: str, endpoint: str, credentials: Path, tmp_path: Path
           ) -> tuple[list[tuple[float, float]], list[float | None], Path]:
    """Subscribe, run the distributed loop, collect robot 1's poses and the clearances."""
    pose_topic = POSE_TOPIC.format(id=1)
    channels = _advertised(ws, {pose_topic, "/scene", "/clearance"})
    pose = channels[pose_topic]
    assert pose["encoding"] == "protobuf" and pose["schemaName"] == "foxglove.PoseInFrame"
    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": 7, "channelId": pose["id"]},
        {"id": 8, "channelId": channels["/clearance"]["id"]}]}))
    out = tmp_path / "out"
    launch = subprocess.run(
        [sys.executable, "-m", "services.launch", "--scenario", "paper-s2", "--scheme",
         "decentralized", "--t-end", "5", "--run", run, "--connect", endpoint,
         "--credentials", str(credentials), "--out",
         str(out), "--no-plots"], capture_output=True, text=True, timeout=100, cwd=REPO)
    assert launch.returncode == 0, launch.stderr
    decode = DecoderFactory().decoder_for("protobuf", Schema(
        id=1, name=pose["schemaName"], encoding="protobuf",
        data=base64.b64decode(pose["schema"])))
    poses, clearances = [], []
    while len(poses) < 10 or len(clearances) < 10:  # samples 0..9
        try:
            msg = ws.recv(timeout=30.0)
        except Exception as exc:
            raise AssertionError(f"received {len(poses)} poses, {len(clearances)} "
                                 "clearances") from exc
        if isinstance(msg, bytes) and msg[0] == 0x01:  # message data
            sub = struct.unpack_from("<I", msg, 1)[0]
            payload = msg[1 + 4 + 8:]
            if sub == 7:
                p = decode(payload).pose.position
                poses.append((p.x, p.y))
            elif sub == 8:
                clearances.append(json.loads(payload)["min"])
    return poses, clearances, out
