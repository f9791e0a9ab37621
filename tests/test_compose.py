"""docker/docker-compose.yml: its services' commands, run as local processes through a router.

No Docker here: the compose file is parsed with PyYAML and every service's
``command`` is started with this interpreter, the host ``router`` replaced by
127.0.0.1 and the router's port by a free one; the run is shortened with
``--t-end``.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from services.testing import free_ports, start_service, stop_processes
from sqpmpc.scenario import load_scenario

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parent.parent
COMPOSE = ROOT / "docker" / "docker-compose.yml"
T_END = "20.0"


def _compose() -> dict:
    return yaml.safe_load(COMPOSE.read_text())


def _option(cmd: list[str], flag: str) -> str | None:
    return cmd[cmd.index(flag) + 1] if flag in cmd else None


def test_compose_file_describes_router_plant_and_one_service_per_robot():
    services = _compose()["services"]
    assert "router" in services and "plant" in services
    router_cmd = services["router"]["command"]
    assert router_cmd[:3] == ["python", "-m", "services.router"]
    plant_cmd = services["plant"]["command"]
    scenario = _option(plant_cmd, "--scenario")
    robots = {name: s["command"] for name, s in services.items()
              if s["command"][2] == "services.robot"}
    ids = sorted(int(_option(cmd, "--id")) for cmd in robots.values())
    assert ids == sorted(int(i) for i in load_scenario(scenario).ids)
    for name, service in services.items():
        cmd = service["command"]
        assert service.get("image") == "sqpmpc:latest"
        if name != "router":
            assert _option(cmd, "--connect") == "tcp/router:7447", name
            assert _option(cmd, "--run") == _option(plant_cmd, "--run"), name
            assert _option(cmd, "--scenario") == scenario, name
    dockerfile = (ROOT / "docker" / "Dockerfile").read_text()
    assert "pip install ." in dockerfile


def _local(cmd: list[str], port: int, run: str) -> tuple[str, list[str]]:
    """The compose command as a local one: host, port, run name, output and length."""
    assert cmd[:2] == ["python", "-m"] and cmd[2].startswith("services.")
    module = cmd[2].split(".", 1)[1]
    args = [a.replace("tcp/router:7447", f"tcp/127.0.0.1:{port}")
            .replace("tcp/0.0.0.0:7447", f"tcp/127.0.0.1:{port}") for a in cmd[3:]]
    if "--run" in args:
        args[args.index("--run") + 1] = run
    if module in ("plant", "robot", "central"):
        args += ["--t-end", T_END]
    return module, args


def test_compose_services_run_locally_through_a_router(tmp_path):
    services = _compose()["services"]
    (port,) = free_ports(1)
    out = tmp_path / "out"
    procs = []
    try:
        module, args = _local(services["router"]["command"], port, "compose-test")
        router = start_service(module, args, tmp_path / "logs", name="router")
        procs.append(router)
        plant = None
        for name, service in services.items():
            if name == "router":
                continue
            module, args = _local(service["command"], port, "compose-test")
            if name == "plant":
                args[args.index("--out") + 1] = str(out)
                args.append("--no-plots")
            proc = start_service(module, args, tmp_path / "logs", name=name)
            procs.append(proc)
            if name == "plant":
                plant = proc
        assert plant is not None
        assert plant.wait(90) == 0, plant.output()
        for proc in procs[1:]:
            assert proc.wait(30) == 0, proc.output()
        assert router.proc.poll() is None, router.output()  # still routing
    finally:
        stop_processes(procs)
    assert router.proc.returncode == 0, router.output()
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["completed"] is True
    assert metrics["collisions"] == 0
    assert metrics["steps"] == 40 and metrics["missed_deadlines"] == 0
    assert (out / "trajectory.npz").exists()
