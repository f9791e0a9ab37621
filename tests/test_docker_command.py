"""``sqpmpc docker``: a compose file for any scenario, a credentials volume per service.

No Docker engine here: the generated file is checked as data (tests/test_compose.py runs
the hand-written demo's commands as local processes).
"""

from __future__ import annotations

from pathlib import Path

import yaml

from services.docker import PORT
from sqpmpc.cli.main import main as sqpmpc_main

# a guard against a hang only (no budget on how long a right run takes on a busy machine)


def _generate(tmp_path: Path, *args: str) -> dict:
    out = tmp_path / "stack"
    assert sqpmpc_main(["docker", *args, "--out", str(out)]) == 0
    return yaml.safe_load((out / "compose.yml").read_text())


def test_a_sixteen_robot_stack_with_a_volume_per_identity(tmp_path):
    data = _generate(tmp_path, "--scenario", "swap-16")
    services = data["services"]
    robots = [f"robot-{i}" for i in range(1, 17)]
    assert set(services) == {"credentials", "router", "plant", *robots}
    for name in ["plant", "router", *robots]:  # only its own identity's volume
        mounts = [v for v in services[name]["volumes"] if v.startswith("id-")]
        assert mounts == [f"id-{name}:/credentials:ro"], (name, mounts)
    issuer = services["credentials"]
    assert len([v for v in issuer["volumes"] if v.startswith("id-")]) == 18
    command = issuer["command"][2]
    assert "--scenario swap-16" in command and "--router-listen tls/0.0.0.0:7447" in command
    assert all(f"/id/{n}/" in command for n in robots)
    assert services["router"]["command"] == ["--config", "/credentials/router.json5"]
    assert services["router"]["ports"] == [f"127.0.0.1:${{SQPMPC_PORT:-{PORT}}}:7447"]
    assert PORT != 7447
    for name in robots:
        assert services[name]["restart"] == "on-failure"
        assert services[name]["depends_on"]["credentials"] == {
            "condition": "service_completed_successfully"}
    assert services["plant"]["user"] == "${SQPMPC_UID:-1000}:${SQPMPC_GID:-1000}"
    assert "chown -R ${SQPMPC_UID:-1000}:${SQPMPC_GID:-1000} /id/plant" in command
    assert "chown -R 1000:1000 /id/robot-1 " in command
    plant = services["plant"]["command"]
    assert "--no-plots" in plant and "--out" not in plant  # a new run folder per run
    assert "${SQPMPC_RUNS:-./runs}:/runs" in services["plant"]["volumes"]
    assert all(s.get("stop_grace_period", "10s") == "10s" for s in services.values())


def test_a_scenario_file_is_mounted_and_overrides_passed(tmp_path):
    scenario = tmp_path / "mine.toml"
    assert sqpmpc_main(["generate", "swap", "--robots", "3", "--out", str(scenario)]) == 0
    data = _generate(tmp_path, "--scenario", str(scenario), "--t-end", "5",
                     "--python-router")
    services = data["services"]
    assert set(services) == {"credentials", "router", "plant", "robot-1", "robot-2",
                             "robot-3"}
    assert "../mine.toml:/scenario.toml:ro" in services["robot-1"]["volumes"]
    assert services["robot-1"]["command"][-2:] == ["--t-end", "5.0"]
    assert services["router"]["command"][:3] == ["python", "-m", "services.router"]


def test_bad_input_and_an_existing_file_are_refused(tmp_path, capsys):
    out = tmp_path / "stack"
    assert sqpmpc_main(["docker", "--scenario", "nope", "--out", str(out)]) == 2
    _generate(tmp_path, "--scenario", "paper-s2")
    assert sqpmpc_main(["docker", "--scenario", "paper-s2", "--out", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    # --up on the stack of another scenario is refused too
    assert sqpmpc_main(["docker", "--scenario", "swap-6", "--out", str(out), "--up"]) == 2
    assert "not of swap-6" in capsys.readouterr().err
    assert sqpmpc_main(["docker", "--scenario", "paper-s2", "--out", str(out),
                        "--overwrite"]) == 0


# ------------------------------------------------------------- --up, with a fake engine
FAKE_DOCKER = '''#!{python}
"""A stand-in for `docker compose -f FILE CMD ...`: the containers' states in a JSON file."""
import json, os, sys, time
import pytest
import yaml
state_file = os.path.join(os.environ["FAKE_DOCKER_DIR"], "state.json")


def logged():  # after the command took effect: a test reading the log sees its effect
    with open(os.path.join(os.environ["FAKE_DOCKER_DIR"], "calls.log"), "a") as log:
        log.write(" ".join(sys.argv[4:]) + "\\n")


cmd = sys.argv[4]
if cmd == "logs":
    logged()
if cmd == "up":
    services = yaml.safe_load(open(sys.argv[3]))["services"]
    states = {{n: ["running", 0] for n in services}}
    states["credentials"] = ["exited", 0]
    json.dump(states, open(state_file + ".tmp", "w"))
    os.replace(state_file + ".tmp", state_file)
elif cmd == "ps":
    states = json.load(open(state_file))
    for name, (state, code) in states.items():
        print(json.dumps({{"Service": name, "State": state, "ExitCode": code}}))
elif cmd == "start":
    states = json.load(open(state_file))
    states[sys.argv[5]] = ["running", 0]
    json.dump(states, open(state_file + ".tmp", "w"))
    os.replace(state_file + ".tmp", state_file)
if cmd == "logs":
    print("plant: status line", flush=True)
    time.sleep(3600)
else:
    logged()
'''


def _fake_docker(tmp_path: Path) -> Path:
    import sys

    path = tmp_path / "docker"
    path.write_text(FAKE_DOCKER.format(python=sys.executable))
    path.chmod(0o755)
    return path


def _set(tmp_path: Path, service: str, state: str, code: int) -> None:
    import json
    import os

    states = json.loads((tmp_path / "state.json").read_text())
    states[service] = [state, code]
    (tmp_path / "state.tmp").write_text(json.dumps(states))
    os.replace(tmp_path / "state.tmp", tmp_path / "state.json")


def _calls(tmp_path: Path) -> list[str]:
    log = tmp_path / "calls.log"
    return log.read_text().splitlines() if log.exists() else []


def test_up_restarts_a_killed_robot_and_ends_with_the_plant(tmp_path, monkeypatch, capsys):
    import threading
    import time

    from services import docker

    monkeypatch.setenv("FAKE_DOCKER_DIR", str(tmp_path))
    monkeypatch.setattr(docker, "POLL", 0.02)
    fake = _fake_docker(tmp_path)

    def engine() -> None:  # what the containers do, seen through `ps`
        while not (tmp_path / "state.json").exists():
            time.sleep(0.01)
        _set(tmp_path, "robot-2", "exited", 137)  # docker kill robot-2
        while "start robot-2" not in _calls(tmp_path):
            time.sleep(0.01)
        _set(tmp_path, "plant", "exited", 0)  # the run completed

    driver = threading.Thread(target=engine)
    driver.start()
    status = sqpmpc_main(["docker", "--scenario", "paper-s2", "--out", str(tmp_path / "s"),
                          "--up", "--docker", str(fake)])
    driver.join()
    assert status == 0
    calls = _calls(tmp_path)
    assert calls[0] == "up -d --build"
    assert calls.count("start robot-2") == 1 and not any(
        c.startswith("start robot-1") for c in calls)
    assert calls[-1] == "down -t 10"  # the stack removed, the volumes kept
    out = capsys.readouterr().out
    assert "robot-2 ended with status 137: starting it again" in out
    assert "the plant ended with status 0" in out
    assert (tmp_path / "s" / "runs").is_dir()


def test_up_stops_the_stack_on_ctrl_c(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    fake = _fake_docker(tmp_path)
    env = dict(os.environ, FAKE_DOCKER_DIR=str(tmp_path))
    proc = subprocess.Popen([sys.executable, "-m", "sqpmpc", "docker", "--scenario",
                             "paper-s2", "--out", str(tmp_path / "s"), "--up", "--docker",
                             str(fake)], env=env, stdout=subprocess.PIPE, text=True,
                            cwd=Path(__file__).resolve().parent.parent)
    try:
        while not any(c.startswith("ps ") for c in _calls(tmp_path)):  # it is watching
            assert proc.poll() is None
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130
    assert _calls(tmp_path)[-1] == "down -t 10"
    assert "stopping the stack (at most 10 s" in out


# ------------------------------------- the generated stack's commands as local processes
def test_a_generated_six_robot_stack_runs_with_one_identity_per_folder(tmp_path):
    """swap-6 (a fleet the hand-written file's 4-robot ACL would drop): the generated
    services' commands run as local processes, each given a folder holding only its own
    identity's files (what its volume holds), through the Python router with the ACL
    issued for the scenario; every robot's inputs arrive."""
    import json
    import shlex

    from services.testing import free_ports, start_service, stop_processes

    data = _generate(tmp_path, "--scenario", "swap-6", "--python-router", "--t-end", "3")
    services = data["services"]
    (port,) = free_ports(1)
    issue = services["credentials"]["command"][2].split(" && ")
    words = shlex.split(issue[0])
    assert words[:4] == ["python", "-m", "sqpmpc", "credentials"]
    every = tmp_path / "c"
    local = [str(every) if w in ("/tmp/c", "/credentials") else
             w.replace("tls/0.0.0.0:7447", f"tls/127.0.0.1:{port}") for w in words[4:]]
    assert sqpmpc_main(["credentials", *local]) == 0
    # each identity's volume: what the issuer copies into /id/<identity>
    folders = {}
    for step in issue[1:]:
        if step.startswith("cp "):
            *sources, target = shlex.split(step)[1:]
            identity = target.strip("/").split("/")[-1]
            folder = tmp_path / "id" / identity
            folder.mkdir(parents=True)
            for pattern in sources:
                for path in every.glob(pattern.replace("/tmp/c/", "")):
                    text = path.read_text().replace(str(every), str(folder))
                    (folder / path.name).write_text(text)
            folders[identity] = folder
    assert set(folders) == {"plant", "router", *(f"robot-{i}" for i in range(1, 7))}
    for identity, folder in folders.items():  # only its own key
        assert [p.name for p in folder.glob("*.key")] == [f"{identity}.key"]
    out, logs = tmp_path / "out", tmp_path / "logs"

    def local(name: str) -> tuple[str, list[str]]:
        cmd = services[name]["command"]
        assert cmd[:2] == ["python", "-m"]
        args = [a.replace("tls/router:7447", f"tls/127.0.0.1:{port}")
                .replace("/credentials", str(folders[name])) for a in cmd[3:]]
        return cmd[2].split(".", 1)[1], args

    procs = []
    try:
        module, args = local("router")
        procs.append(start_service(module, args, logs, name="router"))
        module, args = local("plant")
        plant = start_service(module, [*args, "--out", str(out)], logs, name="plant")
        procs.append(plant)
        for i in range(1, 7):
            module, args = local(f"robot-{i}")
            procs.append(start_service(module, args, logs, name=f"robot-{i}"))
        assert plant.proc.wait() == 0, plant.output()  # the timeout guards a hang
    finally:
        stop_processes(procs)
    metrics = json.loads(next(out.glob("**/metrics.json")).read_text())
    assert metrics["completed"] is True and metrics["steps"] == 6
    assert not metrics.get("never_controlled") and metrics["invalid_messages"] == 0
