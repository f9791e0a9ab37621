"""The live viewer beside a real lockstep run, read by real Foxglove WebSocket clients.

The viewer listens on a loopback Zenoh endpoint, the launcher's plant connects
to it (``services.launch --connect``), and clients of Foxglove's WebSocket
protocol subscribe to pose channels and decode what they receive with the
protobuf schema the server advertised: a ``websockets`` client speaking
``foxglove.sdk.v1`` (foxglove-sdk's own), and Foxglove's ``@foxglove/ws-protocol``
client under Node speaking ``foxglove.websocket.v1`` (the protocol's v1, as
Lichtblick does; its npm packages are pinned in ``tests/node/package.json``).
Only the run's clients get in: the token of the URL the viewer prints, and
browser pages of the allowed origins.
"""

from __future__ import annotations

import base64
import json
import re
import shutil
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory
from websockets.exceptions import InvalidStatus
from websockets.sync.client import ClientConnection, connect

from services.testing import (
    REPO,
    ServiceProcess,
    free_ports,
    start_service,
    stop_processes,
)
from sqpmpc.io.recording import POSE_TOPIC
from tests import HANG

SUBPROTOCOL = "foxglove.sdk.v1"
NODE_CLIENT = REPO / "tests" / "node"


def _wait_serving(viewer: ServiceProcess, timeout: float = HANG) -> str:
    """Wait for the viewer's URL line; returns the URL (with its token)."""
    deadline = time.monotonic() + timeout
    while (found := re.search(r"viewer: open (ws://\S+) in Foxglove", viewer.output())) is None:
        assert viewer.proc.poll() is None and time.monotonic() < deadline, viewer.output()
        time.sleep(0.1)
    return found.group(1)


def _credentials(tmp_path: Path, run: str) -> Path:
    credentials = tmp_path / "credentials"  # the run's, shared by the viewer and the launcher
    made = subprocess.run([sys.executable, "-m", "sqpmpc", "credentials", "--scenario",
                           "paper-s2", "--run", run, "--out", str(credentials)],
                          capture_output=True, text=True, timeout=HANG, cwd=REPO)
    assert made.returncode == 0, made.stderr
    return credentials


def _launch(run: str, endpoint: str, credentials: Path, out: Path) -> None:
    launch = subprocess.run(
        [sys.executable, "-m", "services.launch", "--scenario", "paper-s2", "--scheme",
         "decentralized", "--t-end", "5", "--run", run, "--connect", endpoint,
         "--credentials", str(credentials), "--out",
         str(out), "--no-plots"], capture_output=True, text=True, timeout=HANG, cwd=REPO)
    assert launch.returncode == 0, launch.stderr


def _start_viewer(tmp_path: Path, run: str, credentials: Path, endpoint: str,
                  wsport: int) -> ServiceProcess:
    return start_service("viewer", ["--scenario", "paper-s2", "--t-end", "5", "--run", run,
                                    "--listen", endpoint, "--port", str(wsport),
                                    "--credentials", str(credentials),
                                    "--exit-on-done"], tmp_path / "logs")


def _advertised(ws: ClientConnection, topics: set[str]) -> dict[str, dict]:
    """Channels advertised by the server, by topic, until every one of ``topics`` is seen."""
    channels: dict[str, dict] = {}
    while not topics <= set(channels):
        msg = ws.recv(timeout=HANG)
        if isinstance(msg, str):
            data = json.loads(msg)
            if data.get("op") == "advertise":
                channels.update({c["topic"]: c for c in data["channels"]})
    return channels


def test_viewer_serves_the_poses_of_a_lockstep_run(tmp_path: Path) -> None:
    run = "viewer-test"
    zport, wsport = free_ports(2)
    endpoint = f"tls/127.0.0.1:{zport}"
    credentials = _credentials(tmp_path, run)
    viewer = _start_viewer(tmp_path, run, credentials, endpoint, wsport)
    procs = [viewer]
    try:
        url = _wait_serving(viewer)
        assert url.startswith(f"ws://127.0.0.1:{wsport}/?token=")
        with connect(url, subprotocols=[SUBPROTOCOL],
                     max_queue=None) as ws:  # buffer everything while the run runs
            assert ws.subprotocol == SUBPROTOCOL
            poses, clearances, out = _watch(ws, run, endpoint, credentials, tmp_path)
        assert viewer.wait(HANG) == 0, viewer.output()
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


def _refused(url: str, status: int, **kwargs: object) -> None:
    with pytest.raises(InvalidStatus) as info:
        connect(url, subprotocols=[SUBPROTOCOL], **kwargs)
    assert info.value.response.status_code == status, info.value


def test_the_viewer_admits_only_the_runs_clients(tmp_path: Path) -> None:
    run = "viewer-gate"
    zport, wsport = free_ports(2)
    credentials = _credentials(tmp_path, run)
    viewer = _start_viewer(tmp_path, run, credentials, f"tls/127.0.0.1:{zport}", wsport)
    try:
        url = _wait_serving(viewer)
        token = url.split("token=", 1)[1]
        bare = f"ws://127.0.0.1:{wsport}/"
        _refused(bare, 401)  # no token
        _refused(bare + "?token=" + "x" * len(token), 401)  # a wrong one
        _refused(bare, 401, additional_headers={"Authorization": "Bearer nope"})
        _refused(url, 403, origin="https://evil.example")  # a foreign web page with the token
        for ok in ({"origin": "https://app.foxglove.dev"}, {}):  # Foxglove's web app, a program
            with connect(url, subprotocols=[SUBPROTOCOL], **ok) as ws:
                assert json.loads(ws.recv(timeout=HANG))["op"] == "serverInfo"
        with connect(bare, subprotocols=["foxglove.websocket.v1"],
                     additional_headers={"Authorization": f"Bearer {token}"}) as ws:
            assert ws.subprotocol == "foxglove.websocket.v1"
            assert json.loads(ws.recv(timeout=HANG))["op"] == "serverInfo"
        if shutil.which("node"):  # the Node client without the token is refused too
            _npm_install()
            node = subprocess.run(["node", "pose_client.mjs", bare, "4", "1"],
                                  capture_output=True, text=True, timeout=HANG, cwd=NODE_CLIENT)
            assert node.returncode == 3, node.stdout + node.stderr
            assert '"status":401' in node.stdout
    finally:
        stop_processes([viewer])
    assert "refused a client without the run's token" in viewer.output()
    assert "refused a client from origin https://evil.example" in viewer.output()


def _npm_install() -> None:
    """The Node client's packages, as pinned by tests/node/package-lock.json."""
    if (NODE_CLIENT / "node_modules" / "@foxglove" / "ws-protocol").is_dir():
        return
    done = subprocess.run(["npm", "ci", "--no-audit", "--no-fund"], capture_output=True,
                          text=True, timeout=300, cwd=NODE_CLIENT)
    assert done.returncode == 0, done.stdout + done.stderr


@pytest.mark.skipif(shutil.which("node") is None, reason="needs Node.js (CI has it)")
def test_a_node_foxglove_v1_client_receives_every_robots_pose(tmp_path: Path) -> None:
    _npm_install()
    run = "viewer-node"
    zport, wsport = free_ports(2)
    endpoint = f"tls/127.0.0.1:{zport}"
    credentials = _credentials(tmp_path, run)
    viewer = _start_viewer(tmp_path, run, credentials, endpoint, wsport)
    lines = tmp_path / "node.jsonl"
    node = None
    try:
        url = _wait_serving(viewer)
        with open(lines, "w") as sink:
            node = subprocess.Popen(["node", "pose_client.mjs", url, "4", "10"], stdout=sink,
                                    stderr=subprocess.PIPE, text=True, cwd=NODE_CLIENT)
        deadline = time.monotonic() + HANG  # subscribed to the 4 pose channels
        while lines.read_text().count('"event":"channel"') < 4:
            assert node.poll() is None and time.monotonic() < deadline, lines.read_text()
            time.sleep(0.1)
        out = tmp_path / "out"
        _launch(run, endpoint, credentials, out)
        _, err = node.communicate(timeout=HANG)
        assert node.returncode == 0, lines.read_text() + err
        assert viewer.wait(HANG) == 0, viewer.output()
    finally:
        if node is not None and node.poll() is None:
            node.kill()
            node.wait()
        stop_processes([viewer])
    events = [json.loads(line) for line in lines.read_text().splitlines()]
    assert events[0] == {"event": "open", "protocol": "foxglove.websocket.v1"}
    channels = {e["topic"]: e for e in events if e["event"] == "channel"}
    assert set(channels) == {POSE_TOPIC.format(id=i) for i in (1, 2, 3, 4)}
    states = np.load(out / "trajectory.npz")["states"]
    for j, (topic, channel) in enumerate(sorted(channels.items())):
        decode = DecoderFactory().decoder_for("protobuf", Schema(
            id=1, name=channel["schemaName"], encoding="protobuf",
            data=base64.b64decode(channel["schema"])))
        poses = [decode(base64.b64decode(e["payload"])).pose.position for e in events
                 if e["event"] == "message" and e["topic"] == topic]
        # every sample of every robot, in order: robot j's trajectory (samples 0..9)
        np.testing.assert_array_equal([(p.x, p.y) for p in poses[:10]], states[:-1, j, :2])
    assert events[-1] == {"event": "done"}


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
    _launch(run, endpoint, credentials, out)
    decode = DecoderFactory().decoder_for("protobuf", Schema(
        id=1, name=pose["schemaName"], encoding="protobuf",
        data=base64.b64decode(pose["schema"])))
    poses, clearances = [], []
    while len(poses) < 10 or len(clearances) < 10:  # samples 0..9
        try:
            msg = ws.recv(timeout=HANG)
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
