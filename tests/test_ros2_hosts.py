"""Hosts on one machine (services.netns) and the delaying relay (services.relay).

The lab needs root (network namespaces, veth links, iptables): without it the
lab's test is skipped, saying why (:func:`services.netns.lab_problem`).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from services.netns import HostLab, lab_problem
from services.ros2.hosts import merge_poses
from sqpmpc.errors import ProblemError
from tests import HANG


def test_merge_poses_takes_the_time_every_host_covers():
    parts = [{"epoch": 5.0, "start": 1.0, "end": 30.0, "rate": 50.0, "odom_stop": {},
              "robots": {"1": {"diameter": 0.3, "segments": [[1.0, 0, 0, 0, 0, 0]]}}},
             {"epoch": 5.0, "start": 2.0, "end": 29.0, "rate": 50.0, "odom_stop": {"2": 8.0},
              "robots": {"2": {"diameter": 0.3, "segments": [[2.0, 1, 0, 0, 0, 0]]}}}]
    merged = merge_poses(parts)
    assert (merged["start"], merged["end"]) == (2.0, 29.0)
    assert sorted(merged["robots"]) == ["1", "2"] and merged["odom_stop"] == {"2": 8.0}
    parts[1]["epoch"] = 6.0
    with pytest.raises(ProblemError, match="different epochs"):
        merge_poses(parts)


def test_lab_links_lose_packets_the_relay_delays_and_close_removes_everything():
    problem = lab_problem()
    if problem:
        pytest.skip(f"no network namespaces here: {problem}")
    delay = 0.03
    lab = HostLab(2, loss=0.1, net=202, tag=f"t{os.getpid()}")
    procs = []
    with lab:
        host = lab.hosts[1]
        py = [sys.executable, "-m", "services.relay"]
        procs.append(subprocess.Popen(lab.hub_argv(*py, "echo", "--tcp", "127.0.0.1:9001",
                                                   "--udp", f"{host.hub_address}:9002")))
        procs.append(subprocess.Popen(lab.hub_argv(
            *py, "relay", "--delay", repr(delay), "--route",
            f"{host.hub_address}:9003=127.0.0.1:9001")))
        try:
            out = subprocess.run(host.argv(*py, "probe", "--tcp", f"{host.hub_address}:9003",
                                           "--udp", f"{host.hub_address}:9002", "--count",
                                           "60", "--interval", "0.005"),
                                 capture_output=True, text=True, timeout=HANG, check=False)
            packets = lab.packets()
        finally:
            for p in procs:
                p.terminate()
            for p in procs:
                p.wait(HANG)
        assert out.returncode == 0, out.stderr
        probe = json.loads(out.stdout)
        assert probe["udp_round_trip_loss"] > 0.0  # 0.81^60: never all through
        assert probe["tcp_rtt"]["min"] >= 2 * delay  # the relay held each way
        total, dropped = packets[host.index]
        assert 0 < dropped < total
        names = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True,
                               check=True).stdout
        assert lab.hub in names
    names = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True,
                           check=True).stdout
    assert all(ns not in names for ns in [lab.hub, *(h.namespace for h in lab.hosts)])
