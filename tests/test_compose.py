"""docker/docker-compose.yml: its services' commands, run as local processes through a router.

No Docker here: the compose file is parsed with PyYAML and every service's
``command`` is started with this interpreter: the one-shot ``credentials``
service writes into a temporary folder instead of the ``/credentials`` volume,
the router (``eclipse/zenoh``, not installed here) is ``services.router`` with
the same config file ``docker/zenohd.json5`` (its ``/credentials`` paths and
port mapped to the local ones), the host ``router`` is 127.0.0.1 and its port
a free one; the run is shortened with ``--t-end``.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from services.testing import free_ports, start_service, stop_processes
from sqpmpc.cli.main import main as sqpmpc_main
from sqpmpc.problem.scenario_file import load_scenario

# a guard against a hang only (no budget on how long a right run takes on a busy machine)
pytestmark = pytest.mark.timeout(600)

ROOT = Path(__file__).resolve().parent.parent
COMPOSE = ROOT / "docker" / "docker-compose.yml"
OVERRIDE = ROOT / "docker" / "docker-compose.python-router.yml"
ZENOHD = ROOT / "docker" / "zenohd.json5"
T_END = "20.0"
VOLUME = "/credentials"


def _compose() -> dict:
    return yaml.safe_load(COMPOSE.read_text())


def _option(cmd: list[str], flag: str) -> str | None:
    return cmd[cmd.index(flag) + 1] if flag in cmd else None


def _json5(text: str) -> dict:
    """The zenohd config: JSON after its leading ``//`` comment lines."""
    return json.loads("\n".join(ln for ln in text.splitlines() if not ln.startswith("//")))


def test_compose_file_describes_a_secured_router_plant_and_one_service_per_robot(tmp_path):
    services = _compose()["services"]
    assert {"credentials", "router", "plant"} <= set(services)
    router = services["router"]
    # the router is Eclipse Zenoh's image, pinned to the Python package's version
    assert router["image"] == f"eclipse/zenoh:{importlib.metadata.version('eclipse-zenoh')}"
    assert router["command"] == ["--config", "/zenohd.json5"]
    assert "./zenohd.json5:/zenohd.json5:ro" in router["volumes"]
    assert router["ports"] == ["127.0.0.1:7447:7447"]  # for host tools, loopback only
    creds_cmd = services["credentials"]["command"]
    assert creds_cmd[:4] == ["python", "-m", "sqpmpc", "credentials"]
    assert _option(creds_cmd, "--out") == VOLUME
    plant_cmd = services["plant"]["command"]
    scenario = _option(plant_cmd, "--scenario")
    robots = {name: s["command"] for name, s in services.items()
              if s["command"][2:3] == ["services.robot"]}
    ids = sorted(int(_option(cmd, "--id")) for cmd in robots.values())
    assert ids == sorted(int(i) for i in load_scenario(scenario).ids)
    for name, service in services.items():
        if name in ("credentials", "router"):
            continue
        cmd = service["command"]
        assert service.get("image") == "sqpmpc:latest"
        # healthy: the credentials are written (the one-shot is held, not exited)
        assert service["depends_on"]["credentials"]["condition"] == "service_healthy", name
        assert _option(cmd, "--connect") == "tls/router:7447", name
        assert _option(cmd, "--credentials") == VOLUME, name
        assert _option(cmd, "--run") == _option(creds_cmd, "--run"), name
        assert _option(cmd, "--scenario") == scenario == _option(creds_cmd, "--scenario")
    # docker/zenohd.json5 is the router identity's config the credentials service writes
    out = tmp_path / "creds"
    args = [a if a != VOLUME else str(out) for a in creds_cmd[4:]]
    assert sqpmpc_main(["credentials", *args, "--folder", VOLUME]) == 0
    assert _json5(ZENOHD.read_text()) == json.loads((out / "router.json5").read_text())


def test_the_image_is_built_once_in_cached_layers_and_runs_unprivileged() -> None:
    dockerfile = (ROOT / "docker" / "Dockerfile").read_text()
    steps = [ln.split()[0] + " " + ln.split()[1] for ln in dockerfile.splitlines()
             if ln and not ln.startswith((" ", "#"))]
    # dependencies from pyproject.toml before the source, the kernels compiled at build
    deps = dockerfile.index("pip install -r /tmp/requirements.txt")
    kernels = dockerfile.index("COPY --chown=sqpmpc:sqpmpc sqpmpc/kernels /src/sqpmpc/kernels")
    compiled = dockerfile.index("PYTHONPATH=/src python -m sqpmpc.kernels")
    source = dockerfile.index("COPY --chown=sqpmpc:sqpmpc sqpmpc /src/sqpmpc")
    assert dockerfile.index("COPY --chown=sqpmpc:sqpmpc pyproject.toml") < deps < kernels
    assert kernels < compiled < source < dockerfile.index("pip install --no-deps")
    # compiled for a generic CPU (set before they are compiled): valid on another host
    assert dockerfile.index("NUMBA_CPU_NAME=generic") < compiled
    assert "USER sqpmpc" in steps and steps.index("USER sqpmpc") < steps.index("RUN pip")
    ignored = (ROOT / ".dockerignore").read_text().splitlines()
    assert ignored[ignored.index("*") + 1:] and "*" in ignored  # only what is listed goes in
    assert not (ROOT / "docker" / "Dockerfile.dockerignore").exists()
    services = _compose()["services"]
    built = [name for name, s in services.items() if "build" in s]
    assert built == ["credentials"]  # one build, every other service uses its image
    for name, service in services.items():
        if name != "router":
            assert service["image"] == "sqpmpc:latest", name
            assert "healthcheck" in service, name
    # what ends before the plant is held, so that only the plant's exit ends the stack
    held = sorted(n for n, s in services.items() if s.get("entrypoint") == ["sqpmpc-hold"])
    assert held == sorted(["credentials", *(n for n in services if n.startswith("robot-"))])
    for name, service in services.items():
        if name not in ("credentials", "router"):
            assert service["depends_on"]["credentials"]["condition"] == "service_healthy"


def test_hold_keeps_the_status_and_returns_it_on_sigterm(tmp_path) -> None:
    status = tmp_path / "status"
    env = dict(os.environ, SQPMPC_HOLD_STATUS=str(status))
    proc = subprocess.Popen(["sh", str(ROOT / "docker" / "hold.sh"), sys.executable, "-c",
                             "raise SystemExit(3)"], env=env, stdout=subprocess.PIPE,
                            text=True)
    try:
        line = proc.stdout.readline()
        assert "exited with status 3; holding" in line
        assert status.read_text().strip() == "3" and proc.poll() is None  # held
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 3
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_the_override_puts_the_python_router_in_place_of_eclipse_zenoh() -> None:
    override = yaml.safe_load(OVERRIDE.read_text())["services"]
    router = override["router"]
    assert router["image"] == "sqpmpc:latest"
    assert router["command"] == ["python", "-m", "services.router", "--zenoh-config",
                                 "/zenohd.json5"]
    services = _compose()["services"]
    for name in services:
        if name not in ("credentials", "router"):
            assert override[name]["depends_on"]["router"]["condition"] == "service_healthy"


def _local(cmd: list[str], port: int, creds: Path) -> tuple[str, list[str]]:
    """The compose command as a local one: host, port, credentials folder and run length."""
    assert cmd[:2] == ["python", "-m"] and cmd[2].startswith("services.")
    module = cmd[2].split(".", 1)[1]
    args = [a.replace("tls/router:7447", f"tls/127.0.0.1:{port}").replace(VOLUME, str(creds))
            for a in cmd[3:]]
    if module in ("plant", "robot", "central"):
        args += ["--t-end", T_END]
    return module, args


def test_compose_services_run_locally_through_a_secured_router(tmp_path):
    services = _compose()["services"]
    (port,) = free_ports(1)
    creds, out, logs = tmp_path / "creds", tmp_path / "out", tmp_path / "logs"
    # the one-shot service, into a local folder
    cmd = services["credentials"]["command"]
    assert sqpmpc_main(["credentials", *[a if a != VOLUME else str(creds) for a in cmd[4:]]]) == 0
    # the router with the same config file
    config = tmp_path / "zenohd.json5"
    config.write_text(ZENOHD.read_text().replace(VOLUME + "/", f"{creds}/")
                      .replace("tls/0.0.0.0:7447", f"tls/127.0.0.1:{port}"))
    procs = []
    try:
        router_cmd = yaml.safe_load(OVERRIDE.read_text())["services"]["router"]["command"]
        assert router_cmd[:3] == ["python", "-m", "services.router"]
        router = start_service("router", [a if a != "/zenohd.json5" else str(config)
                                          for a in router_cmd[3:]], logs)
        procs.append(router)
        plant = None
        for name, service in services.items():
            if name in ("credentials", "router"):
                continue
            module, args = _local(service["command"], port, creds)
            if name == "plant":
                args[args.index("--out") + 1] = str(out)
                args.append("--no-plots")
            proc = start_service(module, args, logs, name=name)
            procs.append(proc)
            if name == "plant":
                plant = proc
        assert plant is not None
        assert plant.proc.wait() == 0, plant.output()
        for proc in procs[1:]:
            assert proc.proc.wait() == 0, proc.output()
        assert router.proc.poll() is None, router.output()  # still routing
    finally:
        stop_processes(procs)
    assert router.proc.returncode == 0, router.output()
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["completed"] is True
    assert metrics["collisions"] == 0
    assert metrics["steps"] == 40 and metrics["missed_deadlines"] == 0
    assert metrics["invalid_messages"] == 0
    assert (out / "trajectory.npz").exists()


def test_hold_passes_a_stop_on_to_its_command(tmp_path) -> None:
    env = dict(os.environ, SQPMPC_HOLD_STATUS=str(tmp_path / "status"))
    script = "import signal, sys, time; signal.signal(signal.SIGTERM, lambda *a: sys.exit(7))" \
             "; print('up', flush=True); time.sleep(60)"
    proc = subprocess.Popen(["sh", str(ROOT / "docker" / "hold.sh"), sys.executable, "-c",
                             script], env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "up"
        proc.send_signal(signal.SIGTERM)  # the command gets it and ends with 7
        # and the wrapper ends with it, by itself: no holding after a stop (a stopped stack
        # would otherwise wait for its grace period, then kill it)
        assert proc.wait() == 7
        assert "holding" not in proc.stdout.read()
        assert (tmp_path / "status").read_text().strip() == "7"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
