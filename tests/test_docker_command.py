"""``sqpmpc docker``: a compose file for any scenario, a credentials volume per service.

No Docker engine here: the generated file is checked as data (tests/test_compose.py runs
the hand-written demo's commands as local processes).
"""

from __future__ import annotations

from pathlib import Path

import yaml

from services.docker import PORT
from sqpmpc.cli.main import main as sqpmpc_main


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
        assert services[name]["entrypoint"] == ["sqpmpc-hold"]
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
    assert sqpmpc_main(["docker", "--scenario", "paper-s2", "--out", str(out),
                        "--overwrite"]) == 0
