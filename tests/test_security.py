"""Authenticated, authorized Zenoh traffic: real certificates, real sessions, forged messages.

Every process is a real Zenoh session in a process of its own on 127.0.0.1
(multicast scouting off). The run's credentials are made in the test with
``sqpmpc credentials``; hostile processes are :mod:`services.forger`.
"""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import time

import numpy as np
import pytest
from cryptography import x509
from cryptography.x509.oid import NameOID

from services.credentials import META_FILE, write_credentials
from services.forger import forged_speed
from services.testing import (
    REPO,
    ServiceProcess,
    child_pids,
    free_ports,
    pid_alive,
    start_service,
    stop_processes,
)
from sqpmpc.cli.main import main as sqpmpc_main
from sqpmpc.control.settings import SolverSettings
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import ClosedLoopSimulation, SimulationOptions
from tests import HANG
from tests.service_helpers import assert_lockstep_held

SCENARIO = "paper-s2"
T_END = 20.0  # 40 samples
IDENTITIES = ["plant", "viewer", "robot-1", "robot-2", "robot-3", "robot-4"]
HANG_GUARDS = ("--timeout", str(HANG), "--startup-timeout", str(HANG))
"""The plant's waits (for a sample's inputs in lockstep, for the controllers before sample
0): hang guards only, so that no robot is braked because a busy machine was slow."""


def test_credentials_command_writes_a_private_folder_per_identity(tmp_path, capsys):
    out = tmp_path / "creds"
    assert sqpmpc_main(["credentials", "--scenario", SCENARIO, "--run", "r1", "--out",
                        str(out), "--valid-hours", "2"]) == 0
    assert stat.S_IMODE(out.stat().st_mode) == 0o700
    meta = json.loads((out / META_FILE).read_text())
    assert meta["run"] == "r1" and meta["identities"] == IDENTITIES
    names = {p.name for p in out.iterdir()}
    assert names == {"ca.pem", META_FILE} | {f"{i}.{ext}" for i in IDENTITIES
                                            for ext in ("pem", "key", "json5")}
    for path in out.iterdir():  # the CA's private key is never written
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, path
    ca = x509.load_pem_x509_certificate((out / "ca.pem").read_bytes())
    for identity in IDENTITIES:
        cert = x509.load_pem_x509_certificate((out / f"{identity}.pem").read_bytes())
        cn = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value
        assert cn == identity
        cert.verify_directly_issued_by(ca)
        hours = (cert.not_valid_after_utc - cert.not_valid_before_utc).total_seconds() / 3600
        assert hours <= 2.1
    # least privilege: a decentralized peer-to-peer run has no central and no router key
    assert not {"central", "router"} & set(meta["identities"])
    for extra, expected in ((["--no-viewer"], ["plant", "robot-1", "robot-2", "robot-3",
                                                "robot-4"]),
                            (["--scheme", "centralized", "--router"],
                             ["plant", "router", "viewer", "central"])):
        other = tmp_path / f"creds{len(expected)}"
        assert sqpmpc_main(["credentials", "--scenario", SCENARIO, "--run", "r1", "--out",
                            str(other), *extra]) == 0
        assert json.loads((other / META_FILE).read_text())["identities"] == expected
        assert {p.name for p in other.iterdir()} == {"ca.pem", META_FILE} | {
            f"{i}.{ext}" for i in expected for ext in ("pem", "key", "json5")}
    # the router forwards (its clients accept from it) but its key publishes nothing at
    # the router itself
    at_router = json.loads((other / "router.json5").read_text())["access_control"]
    at_plant = json.loads((other / "plant.json5").read_text())["access_control"]
    router_rules = {p["subjects"][0]: p["rules"] for p in at_router["policies"]}
    assert router_rules["router"] == ["read", "reply-alive"]
    plant_rules = {p["subjects"][0]: p["rules"] for p in at_plant["policies"]}
    assert plant_rules["router"] == ["router-forward"]
    conf = json.loads((out / "robot-1.json5").read_text())
    assert conf["transport"]["link"]["protocols"] == ["tls"]
    assert conf["transport"]["link"]["tls"]["enable_mtls"] is True
    acl = conf["access_control"]
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["robot-1-put"]["key_exprs"] == ["sqpmpc/@v1/r1/robot/1/**"]
    assert rules["plant-put"]["key_exprs"] == ["sqpmpc/@v1/r1/plant/**"]
    assert "viewer-put" not in rules  # the viewer may only subscribe
    capsys.readouterr()
    assert sqpmpc_main(["credentials", "--scenario", "no-such", "--run", "r1", "--out",
                        str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("sqpmpc credentials: error: no-such")


def _wait_ready(proc: ServiceProcess, timeout: float) -> None:
    """Until the forger's session is open, or it gave up (a client no router accepts)."""
    deadline = time.monotonic() + timeout
    while '"ready"' not in proc.output() and proc.proc.poll() is None:
        assert time.monotonic() < deadline, proc.output()
        time.sleep(0.05)


def _summary(proc: ServiceProcess) -> dict:
    lines = [ln for ln in proc.output().splitlines() if ln.startswith('{"opened"')]
    assert lines, proc.output()
    return json.loads(lines[-1])


@pytest.mark.parametrize("topology", ["peer", "router"])
def test_forged_traffic_from_other_processes_changes_nothing(tmp_path, topology):
    """A process holding robot 2's certificate forges robot 1's cmd and plans, the plant's
    states and done, and robot 1's liveliness; processes without the run's certificates
    try the same. The run equals the undisturbed one, bit for bit."""
    run = f"sec-{topology}"
    creds, other = tmp_path / "creds", tmp_path / "other-ca"
    scenario = load_scenario(SCENARIO)
    router_listen = None if topology == "peer" else ()
    write_credentials(creds, scenario, run, "decentralized", router_listen=router_listen)
    # a CA the run does not trust
    write_credentials(other, scenario, run, "decentralized", router_listen=router_listen)
    ports = free_ports(9)
    eps = [f"tls/127.0.0.1:{p}" for p in ports[:5]]  # plant (or router), robots 1-4
    common = ["--scenario", SCENARIO, "--run", run, "--t-end", str(T_END), "--log-level",
              "WARNING", "--credentials", str(creds)]
    logs, out = tmp_path / "logs", tmp_path / "out"
    procs: list[ServiceProcess] = []
    try:
        if topology == "router":
            procs.append(start_service("router", ["--listen", eps[0], "--credentials",
                                                  str(creds)], logs))
            net = ["--zenoh-mode", "client", "--connect", eps[0]]
            plant_net = net
        else:
            net, plant_net = ["--connect", eps[0]], ["--listen", eps[0]]
        plant = start_service("plant", [*common, *plant_net, "--out", str(out), "--no-plots",
                                        "--quiet", *HANG_GUARDS], logs)
        procs.append(plant)
        targets = [eps[0]] if topology == "router" else eps
        hostile = {
            "robot-2": ["--credentials", str(creds), "--identity", "robot-2",
                        "--links", str(len(targets))],
            "other-ca": ["--credentials", str(other), "--identity", "robot-1"],
            "no-certificate": [],
        }
        if topology == "router":  # the router's own key, as a client of the router
            hostile["router-key"] = ["--credentials", str(creds), "--identity", "router",
                                     "--links", "1"]
        forgers = {}
        for name, extra in hostile.items():
            proto = "tcp" if name == "no-certificate" else "tls"
            fnet = [a for t in targets for a in ("--connect", t.replace("tls", proto))]
            if topology == "router":
                fnet += ["--zenoh-mode", "client"]
            else:
                fnet += ["--listen", f"{proto}/127.0.0.1:{ports[5 + len(forgers)]}"]
            forgers[name] = start_service(
                "forger", ["--scenario", SCENARIO, "--run", run, "--t-end", str(T_END),
                           "--duration", "120", "--period", "0.002", *extra, *fnet], logs,
                name=f"forger-{name}")
            procs.append(forgers[name])
        for proc in forgers.values():
            _wait_ready(proc, HANG)
        for j, rid in enumerate(scenario.ids, start=1):
            own = [] if topology == "router" else ["--listen", eps[j]]
            procs.append(start_service("robot", ["--id", str(rid), *common, *own, *net], logs,
                                       name=f"robot-{rid}"))
        assert plant.wait(HANG) == 0, plant.output()
    finally:
        stop_processes(procs)
    summaries = {name: _summary(p) for name, p in forgers.items()}
    insider = summaries["robot-2"]
    # robot 2's certificate lets it in and read the states: it forged during the whole run
    assert insider["opened"] and insider["links"] == len(targets), insider
    assert insider["states_seen"] == 40, insider
    assert insider["sent"]["done"] == 1 and insider["sent"]["cmd"] >= 40, insider
    if topology == "router":  # linked, forging all along: the router took nothing of it
        assert summaries["router-key"]["links"] == 1, summaries["router-key"]
        assert summaries["router-key"]["sent"]["cmd"] >= 40, summaries["router-key"]
    # no certificate of the run's CA: no link at all
    for name in ("other-ca", "no-certificate"):
        s = summaries[name]
        assert not s["opened"] or (s["links"] == 0 and s["states_seen"] == 0), (name, s)
        if topology == "router":  # a client that no router accepts cannot even open
            assert not s["opened"], (name, s)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["completed"] is True and metrics["steps"] == 40
    assert metrics["insecure"] is False  # the plant had its credentials
    assert metrics["collisions"] == 0
    assert_lockstep_held(metrics)  # no robot braked: its own input applied at every sample
    assert metrics["invalid_messages"] == 0  # nothing forged reached a validator
    traj = np.load(out / "trajectory.npz")
    assert not np.any(traj["inputs"][:, :, 0] == forged_speed(scenario.bounds.input_upper()))
    reference = ClosedLoopSimulation(scenario.with_changes(t_end=T_END), "decentralized",
                                     SolverSettings(),
                                     SimulationOptions(decentralized_mode="shared")).run()
    assert np.array_equal(traj["states"], reference.states)
    assert np.array_equal(traj["inputs"], reference.inputs)


def test_a_service_refuses_credentials_of_another_run_or_plain_endpoints(tmp_path):
    creds = tmp_path / "creds"
    write_credentials(creds, load_scenario(SCENARIO), "run-a", "decentralized")
    (port,) = free_ports(1)
    cases = [
        (["--run", "run-b", "--credentials", str(creds)], "were made for run 'run-a'"),
        (["--run", "run-a", "--credentials", str(creds), "--listen",
          f"tcp/127.0.0.1:{port}"], "tls/ endpoints only"),
        (["--run", "run-a", "--zenoh-config", str(tmp_path / "none.json5")], "no such file"),
    ]
    for args, message in cases:
        proc = start_service("plant", ["--scenario", SCENARIO, *args], tmp_path / "logs")
        assert proc.wait(HANG) == 2, proc.output()
        lines = [ln for ln in proc.output().splitlines() if "error" in ln]
        assert len(lines) == 1 and message in lines[0], proc.output()


@pytest.mark.parametrize("offset", [-1, 0], ids=["stale", "current"])
def test_one_inconsistent_input_on_a_robots_own_key_cannot_stop_the_run(tmp_path, offset):
    """Robot 2's own certificate sends one input for robot 2 carrying another settings
    digest (what a controller with other settings sends) at sample 20. Of an older sample
    (``stale``) it is dropped before its digest is read: the run equals the undisturbed one,
    bit for bit. Of the plant's current sample it marks robot 2 faulty at that sample
    (braked); either way the run completes and the forged input is never applied."""
    run = f"one-{'stale' if offset else 'current'}"
    creds = tmp_path / "creds"
    scenario = load_scenario(SCENARIO)
    write_credentials(creds, scenario, run, "decentralized")
    ports = free_ports(6)
    eps = [f"tls/127.0.0.1:{p}" for p in ports]
    common = ["--scenario", SCENARIO, "--run", run, "--t-end", str(T_END), "--log-level",
              "WARNING", "--credentials", str(creds)]
    logs, out = tmp_path / "logs", tmp_path / "out"
    procs: list[ServiceProcess] = []
    try:
        plant = start_service("plant", [*common, "--listen", eps[0], "--out", str(out),
                                        "--no-plots", "--quiet", *HANG_GUARDS], logs)
        procs.append(plant)
        forger = start_service(
            "forger", ["--scenario", SCENARIO, "--run", run, "--t-end", str(T_END),
                       "--credentials", str(creds), "--identity", "robot-2", "--target", "2",
                       "--attack", "settings", "--at", "20", "--sample-offset", str(offset),
                       "--duration", "120", "--connect", eps[0], "--listen", eps[5]], logs,
            name="forger")
        procs.append(forger)
        _wait_ready(forger, HANG)
        for j, rid in enumerate(scenario.ids, start=1):
            procs.append(start_service("robot", ["--id", str(rid), *common, "--listen", eps[j],
                                                 "--connect", eps[0]], logs,
                                       name=f"robot-{rid}"))
        status = plant.wait(HANG)
    finally:
        stop_processes(procs)
    assert _summary(forger)["sent"]["settings"] == 1, forger.output()
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["completed"] is True and metrics["steps"] == 40, plant.output()
    assert metrics["collisions"] == 0
    faulty = metrics["faulty_messages"]
    assert faulty["1"] == faulty["3"] == faulty["4"] == 0
    traj = np.load(out / "trajectory.npz")
    assert not np.any(traj["inputs"][:, :, 0] == forged_speed(scenario.bounds.input_upper()))
    assert "Traceback" not in plant.output()
    if offset < 0:
        assert status == 0, plant.output()
        assert faulty["2"] == 0 and metrics["late_commands"] >= 1
        reference = ClosedLoopSimulation(scenario.with_changes(t_end=T_END), "decentralized",
                                         SolverSettings(),
                                         SimulationOptions(decentralized_mode="shared")).run()
        assert np.array_equal(traj["states"], reference.states)
        assert np.array_equal(traj["inputs"], reference.inputs)
    else:  # it reached the plant at sample 20 or, if the plant had moved on, was stale
        assert faulty["2"] + metrics["late_commands"] >= 1
        assert metrics["missed_deadlines"] == faulty["2"] <= 1
        assert status == (2 if faulty["2"] else 0), plant.output()
        if faulty["2"]:
            assert "collision_margin 0.5 (the plant: 0.001)" in metrics["refused"]


def _key_material(text: bytes) -> bool:
    return b"PRIVATE KEY" in text or b"_private_key" in text or b"LS0tLS1CRUdJTi" in text


def test_a_launch_writes_no_key_and_hands_each_process_only_its_own(tmp_path):
    """``services.launch`` issues the credentials in memory and hands each child its own
    over a socket: no private key in any file (the launcher's temporary folder is gone),
    command line or environment, while running and after a SIGKILL of the launcher; every
    process is non-dumpable (another unprivileged process of the user cannot read its
    memory or descriptors)."""
    # the launcher's temporary folder under a TMPDIR of its own: what other tests or runs on
    # the machine create meanwhile in the shared one is not mistaken for the launcher's
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    out = tmp_path / "out"
    # the launcher's and its children's output in a file: a pipe read only at the end would
    # fill and block a child's write, and the child would then never end
    log = tmp_path / "launch.log"
    with open(log, "wb") as fh:
        launcher = subprocess.Popen(
            [sys.executable, "-m", "services.launch", "--scenario", SCENARIO, "--scheme",
             "decentralized", "--mode", "realtime", "--out", str(out), "--no-plots"],
            cwd=REPO, stdout=subprocess.DEVNULL, stderr=fh, env={**os.environ, "TMPDIR": str(tmp)})
    try:
        deadline = time.monotonic() + HANG  # a loaded machine: imports take long
        record = out / "record.msgpack"
        children: list[int] = []
        while time.monotonic() < deadline and len(children) < 5:
            children = child_pids(launcher.pid)
            time.sleep(0.1)
        while time.monotonic() < deadline and not (record.exists()
                                                   and record.stat().st_size > 0):
            time.sleep(0.1)
        assert record.exists(), log.read_text()
        assert len(children) == 5, "plant and 4 robots"
        for pid in children:
            with open(f"/proc/{pid}/cmdline", "rb") as fh:
                argv = fh.read().split(b"\0")
            assert b"--credentials-fd" in argv and b"--credentials" not in argv
            with open(f"/proc/{pid}/environ", "rb") as fh:  # readable here: root
                assert not _key_material(fh.read())
        launcher.kill()  # SIGKILL: the children get SIGTERM (parent death signal)
        launcher.wait(HANG)
        deadline = time.monotonic() + HANG
        while any(pid_alive(pid) for pid in children) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(pid_alive(pid) for pid in children), log.read_text()
    finally:
        if launcher.poll() is None:
            launcher.kill()
            launcher.wait()
    created = list(tmp.iterdir())
    for root in [out, *[p for p in created if p.name.startswith("sqpmpc")]]:
        for path in [root, *root.rglob("*")] if root.is_dir() else [root]:
            if path.is_file():
                assert not _key_material(path.read_bytes()), path
    assert not [p for p in created if p.name.startswith("sqpmpc-credentials")]
    assert json.loads((out / "metrics.json").read_text())["interrupted"] == "SIGTERM"
    # what the services do with the handed-over socket: non-dumpable first
    probe = subprocess.run(
        [sys.executable, "-c", "import ctypes; from services.handover import make_private; "
         "print(make_private(), ctypes.CDLL(None).prctl(3, 0, 0, 0, 0))"],
        cwd=REPO, capture_output=True, text=True, timeout=HANG)
    assert probe.stdout.split() == ["True", "0"], probe.stderr
