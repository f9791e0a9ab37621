"""docker/paper-s2/compose.yml and docker/Dockerfile: the committed stack is the generated one.

No Docker engine here. The committed compose file is what ``sqpmpc docker --scenario
paper-s2`` writes (so it cannot go stale); the image is built once, in cached layers,
unprivileged, with kernels valid on any x86-64 CPU. ``tests/test_docker_command.py``
runs a generated stack's commands as local processes, each given only its own
identity's files, and drives ``sqpmpc docker --up`` against a stand-in engine.
"""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import yaml

from sqpmpc.cli.main import main as sqpmpc_main

ROOT = Path(__file__).resolve().parent.parent
COMPOSE = ROOT / "docker" / "paper-s2" / "compose.yml"


def _without_build_context(data: dict) -> dict:
    data["services"]["credentials"]["build"].pop("context")
    return data


def test_the_committed_stack_is_what_sqpmpc_docker_writes(tmp_path):
    assert sqpmpc_main(["docker", "--scenario", "paper-s2", "--out", str(tmp_path)]) == 0
    written = yaml.safe_load((tmp_path / "compose.yml").read_text())
    committed = yaml.safe_load(COMPOSE.read_text())
    assert committed["services"]["credentials"]["build"]["context"] == "../.."
    assert _without_build_context(committed) == _without_build_context(written)
    assert "down -v" in COMPOSE.read_text()  # the header says how to remove the volumes


def test_the_paper_s2_stack_holds_a_key_per_container_and_a_pinned_router():
    services = yaml.safe_load(COMPOSE.read_text())["services"]
    assert set(services) == {"credentials", "router", "plant", "robot-1", "robot-2",
                             "robot-3", "robot-4"}
    version = importlib.metadata.version("eclipse-zenoh")
    assert services["router"]["image"] == f"eclipse/zenoh:{version}"
    assert services["router"]["ports"] == ["127.0.0.1:${SQPMPC_PORT:-17447}:7447"]
    for name, service in services.items():
        if name == "credentials":
            continue
        assert [v for v in service["volumes"] if v.startswith("id-")] == [
            f"id-{name}:/credentials:ro"]


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
    services = yaml.safe_load(COMPOSE.read_text())["services"]
    built = [name for name, s in services.items() if "build" in s]
    assert built == ["credentials"]  # one build, every other service uses its image
    for name, service in services.items():
        if name != "router":
            assert service["image"] == "sqpmpc:latest", name
