"""Write a Docker Compose file for a distributed run of any scenario, and run it.

``sqpmpc docker --scenario S [--scheme decentralized|centralized] [--out DIR]
[--python-router] [--t-end T] [--overwrite] [--up]`` writes ``DIR/compose.yml``
(default ``docker/<scenario>``): a one-shot ``credentials`` service (built from the
repository's ``docker/Dockerfile``), the Zenoh router, the plant and one service per
robot (or the central controller), every service a client of the router over mutual TLS.
With ``--up`` it runs the stack to its end (:func:`supervise`).

- **A volume per identity.** The credentials service issues the run's credentials for
  the scenario's identities (so the router's access-control rules are generated for this
  scenario: every robot of it, no other) and copies each identity's certificate, key and
  Zenoh config into that identity's own volume; each service mounts only its own, so
  from robot 1's container no other identity's key is readable. The router's config is
  its identity's (``router.json5``). The others start once it has ended successfully.
- **A run folder per run**: the plant writes into ``${SQPMPC_RUNS:-./runs}`` a new folder
  named after the scenario and the time, as ``${SQPMPC_UID}:${SQPMPC_GID}`` (``--up``
  passes the user's), so the files are the user's; no plots (``sqpmpc metrics`` and
  ``sqpmpc animate`` read the folder).
- **Host port** ``${SQPMPC_PORT:-17447}`` on the loopback (not 7447, the port of a ROS 2
  user's own rmw_zenoh router).
- **A killed robot rejoins**: ``--up`` starts again a controller container that ended
  with a non-zero status while the plant runs (Docker's restart policy, ``on-failure``
  here, does not restart a container stopped by ``docker kill``), and the plant waits for
  it (``--rejoin-timeout``).
- **Stops** within 10 s (``stop_grace_period``).

``docker compose -f DIR/compose.yml down -v`` removes the containers and the credential
volumes. ``docker/paper-s2/compose.yml`` is this command's file for paper-s2.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import yaml

from sqpmpc import __version__
from sqpmpc.cli.options import Parser, add_override_options
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.problem.goals import unreachable_goals
from sqpmpc.problem.scenario_file import builtin_scenario_names, load_scenario

from .credentials import identities

__all__ = ["PORT", "build_parser", "compose_file", "main", "service_states", "supervise"]

PROG = "services.docker"
PORT = 17447
"""Default host port of the router (not 7447: rmw_zenoh's router uses that)."""
ROOT = Path(__file__).resolve().parent.parent
RUN = "compose"
POLL = 1.0
"""Seconds between two looks at the stack's containers (``sqpmpc docker --up``)."""
STATUS_EVERY = 10.0
"""Seconds between two lines on the stack's state while it starts and runs."""
GRACE = 10
"""Seconds each container may take to stop (the compose file's ``stop_grace_period``)."""


def _volume(identity: str) -> str:
    return f"id-{identity}"


#: The plant runs as the user who starts the stack (``sqpmpc docker --up`` sets these), so
#: that the run folders it writes on the host are theirs; every other service as uid 1000.
HOST_USER = "${SQPMPC_UID:-1000}:${SQPMPC_GID:-1000}"


def _owner(identity: str) -> str:
    return HOST_USER if identity == "plant" else "1000:1000"


def compose_file(scenario_arg: str, scheme: str, out: Path, python_router: bool = False,
                 overrides: list[str] | None = None) -> dict[str, Any]:
    """The compose file (as a dict) for ``scenario_arg`` (a built-in name or a file),
    written into the folder ``out`` (paths in it are relative to ``out``)."""
    scenario = load_scenario(scenario_arg)
    names = identities(scenario, scheme, router=True)
    overrides = overrides or []
    volumes_root = {}
    mount_scenario: list[str] = []
    scenario_in = scenario_arg
    if scenario_arg not in builtin_scenario_names():
        host = os.path.relpath(Path(scenario_arg).resolve(), out.resolve())
        mount_scenario = [f"{host}:/scenario.toml:ro"]
        scenario_in = "/scenario.toml"
    copies = " && ".join(
        f"mkdir -p /id/{n} && cp /tmp/c/{n}.* /tmp/c/ca.pem /tmp/c/credentials.json /id/{n}/ "
        f"&& chown -R {_owner(n)} /id/{n} && chmod 700 /id/{n}" for n in names)
    issue = (f"python -m sqpmpc credentials --scenario {scenario_in} --run {RUN} "
             f"--scheme {scheme} --router-listen tls/0.0.0.0:7447 --out /tmp/c "
             f"--folder /credentials && {copies} && rm -rf /tmp/c")
    base = {"image": "sqpmpc:latest", "pull_policy": "never", "init": True,
            "stop_grace_period": "10s"}
    services: dict[str, Any] = {
        "credentials": {  # one-shot: the others start once it has ended successfully
            **base, "pull_policy": "build", "user": "0", "restart": "no",
            "build": {"context": os.path.relpath(ROOT, out.resolve()),
                      "dockerfile": "docker/Dockerfile"},
            "volumes": [f"{_volume(n)}:/id/{n}" for n in names] + mount_scenario,
            "command": ["sh", "-c", issue],
        },
    }
    after = {"credentials": {"condition": "service_completed_successfully"}}
    if python_router:
        services["router"] = {
            **base, "restart": "no", "depends_on": after,
            "volumes": [f"{_volume('router')}:/credentials:ro"],
            "command": ["python", "-m", "services.router", "--zenoh-config",
                        "/credentials/router.json5"],
            "healthcheck": {"test": ["CMD", "python", "-c", "import socket; socket."
                                     "create_connection(('127.0.0.1', 7447), 1).close()"],
                            "interval": "1s", "timeout": "2s", "retries": 120},
        }
        router_ready = {"condition": "service_healthy"}
    else:
        version = importlib.metadata.version("eclipse-zenoh")
        services["router"] = {
            "image": f"eclipse/zenoh:{version}", "init": True, "restart": "no",
            "stop_grace_period": "10s", "depends_on": after,
            "volumes": [f"{_volume('router')}:/credentials:ro"],
            "command": ["--config", "/credentials/router.json5"],
        }
        router_ready = {"condition": "service_started"}
    services["router"]["ports"] = [f"127.0.0.1:${{SQPMPC_PORT:-{PORT}}}:7447"]
    depends = {**after, "router": router_ready}
    common = ["--scenario", scenario_in, "--run", RUN, "--credentials", "/credentials",
              "--zenoh-mode", "client", "--connect", "tls/router:7447", *overrides]
    services["plant"] = {
        **base, "restart": "no", "depends_on": depends, "working_dir": "/",
        "user": HOST_USER, "environment": {"HOME": "/tmp"},
        "volumes": [f"{_volume('plant')}:/credentials:ro", "${SQPMPC_RUNS:-./runs}:/runs",
                    *mount_scenario],
        "command": ["python", "-m", "services.plant", *common, "--scheme", scheme,
                    "--mode", "lockstep", "--startup-timeout", "300", "--no-plots"],
    }
    for name in names:
        if name in ("plant", "router"):
            continue
        cmd = (["python", "-m", "services.central"] if name == "central" else
               ["python", "-m", "services.robot", "--id", name.split("-", 1)[1]])
        services[name] = {
            **base, "restart": "on-failure", "depends_on": depends,
            "volumes": [f"{_volume(name)}:/credentials:ro", *mount_scenario],
            "command": [*cmd, *common],
        }
    volumes_root = {_volume(n): {} for n in names}
    return {"name": f"sqpmpc-{scenario.name}", "services": services, "volumes": volumes_root}


def service_states(text: str) -> dict[str, tuple[str, int]]:
    """``docker compose ps -a --format json`` (a JSON array, or one object per line as
    newer Compose prints it) as ``{service: (state, exit code)}``."""
    text = text.strip()
    if not text:
        return {}
    rows = json.loads(text) if text.startswith("[") else [
        json.loads(line) for line in text.splitlines() if line.strip()]
    return {r["Service"]: (str(r.get("State", "")).lower(), int(r.get("ExitCode") or 0))
            for r in rows}


def supervise(file: Path, controllers: list[str], docker: str = "docker",
              env: dict[str, str] | None = None) -> int:
    """Run the stack of ``file`` to its end and return the plant's exit status.

    ``docker compose up -d --build`` (its own progress), the plant's lines as they come,
    a line on the stack every :data:`STATUS_EVERY` seconds; a controller container that
    ends with a non-zero status while the plant runs (a crash, ``docker kill``) is
    started again and rejoins the run (the plant waits for it, ``--rejoin-timeout``).
    When the plant ends, or on Ctrl-C/SIGTERM (status 128 + signal), the stack is
    stopped (at most :data:`GRACE` s per container: the plant writes what it has) and
    removed, its credential volumes kept for ``down -v``.
    """
    compose = [docker, "compose", "-f", str(file)]
    stop = threading.Event()
    received: dict[str, int] = {}

    def on_signal(sig: int, _frame: Any) -> None:
        received.setdefault("signal", sig)
        stop.set()

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    logs = None
    status = 1
    try:
        print(f"== starting the stack of {file} (the image is built on the first run)",
              flush=True)
        up = subprocess.run([*compose, "up", "-d", "--build"], env=env)
        if up.returncode != 0 or stop.is_set():
            return 128 + received["signal"] if stop.is_set() else up.returncode
        logs = subprocess.Popen([*compose, "logs", "-f", "--no-log-prefix", "plant"], env=env)
        t0 = shown = time.monotonic()
        while not stop.wait(POLL):
            ps = subprocess.run([*compose, "ps", "-a", "--format", "json"], env=env,
                                capture_output=True, text=True)
            states = service_states(ps.stdout) if ps.returncode == 0 else {}
            plant = states.get("plant")
            if plant is not None and plant[0] in ("exited", "dead"):
                status = plant[1]
                print(f"== the plant ended with status {status}", flush=True)
                break
            for name in controllers:
                state, code = states.get(name, ("", 0))
                if state in ("exited", "dead") and code != 0:
                    print(f"== {name} ended with status {code}: starting it again (the plant "
                          "waits for it to rejoin)", flush=True)
                    subprocess.run([*compose, "start", name], env=env)
            now = time.monotonic()
            if now - shown >= STATUS_EVERY:
                shown = now
                running = sum(states.get(n, ("",))[0] == "running" for n in controllers)
                print(f"== {now - t0:.0f} s: plant {plant[0] if plant else 'not started'}, "
                      f"{running}/{len(controllers)} controllers running", flush=True)
        if stop.is_set():
            status = 128 + received["signal"]
            print(f"== stopping the stack (at most {GRACE} s; the plant writes what it has)",
                  flush=True)
    finally:
        subprocess.run([*compose, "down", "-t", str(GRACE)], env=env)
        if logs is not None:
            logs.terminate()
            logs.wait()
        for sig, handler in old.items():
            signal.signal(sig, handler)
    return status


_HEADER = """# Written by `sqpmpc docker {args}`: a distributed run of {scenario} ({n} robots,
# {scheme}) through a Zenoh router, mutual TLS, a credentials volume per service.
#   sqpmpc docker --scenario {scenario_arg} --out {out} --up   # runs it to its end
# or by hand (the plant's status is `wait`'s):
#   SQPMPC_UID=$(id -u) SQPMPC_GID=$(id -g) docker compose -f {file} up -d --build
#   docker compose -f {file} wait plant; docker compose -f {file} down
#   docker compose -f {file} down -v      # also the credential volumes
# SQPMPC_PORT (default {port}): the router's port on the host's loopback;
# SQPMPC_RUNS (default ./runs beside this file): where the plant writes a folder per run.
"""


class _Dumper(yaml.SafeDumper):
    """YAML without anchors: every service written out in full."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    """The argument parser of ``sqpmpc docker``."""
    parser = Parser(prog=prog, description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--scenario", required=True, help="TOML file or built-in name")
    parser.add_argument("--scheme", choices=("decentralized", "centralized"),
                        default="decentralized")
    parser.add_argument("--out", type=Path, default=None,
                        help="folder of compose.yml (default docker/<scenario>)")
    parser.add_argument("--python-router", action="store_true",
                        help="the project's Python router (services.router) in place of the "
                             "eclipse/zenoh image (e.g. where it cannot be pulled)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing compose.yml")
    parser.add_argument("--up", action="store_true",
                        help="then run the stack to its end: its status is the plant's; a "
                             "controller container that dies is started again; Ctrl-C stops "
                             "it within 10 s; a folder per run under OUT/runs")
    parser.add_argument("--docker", default="docker", metavar="PROGRAM",
                        help="the docker command (default docker)")
    add_override_options(parser)
    return parser


def _write(args: argparse.Namespace, argv: list[str], out: Path, target: Path,
           scenario: Any) -> None:
    overrides = [a for flag in ("horizon", "sample_time", "t_end")
                 if getattr(args, flag) is not None
                 for a in (f"--{flag.replace('_', '-')}", repr(getattr(args, flag)))]
    data = compose_file(args.scenario, args.scheme, out, args.python_router, overrides)
    out.mkdir(parents=True, exist_ok=True)
    header = _HEADER.format(args=" ".join(argv), scenario=scenario.name,
                            scenario_arg=args.scenario, out=out, n=scenario.n_robots,
                            scheme=args.scheme, file=target, port=PORT)
    target.write_text(header + yaml.dump(data, Dumper=_Dumper, sort_keys=False, width=100))
    print(f"wrote {target}: {scenario.n_robots} robots, {args.scheme}", flush=True)


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Entry point: 0 written (``--up``: the plant's status), 2 bad input."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(prog).parse_args(argv)
    try:
        scenario = load_scenario(args.scenario)
        unreachable = unreachable_goals(scenario)
        if unreachable:
            raise ProblemError(unreachable[0])
        out = args.out or Path("docker") / scenario.name
        target = out / "compose.yml"
        if target.exists() and not args.overwrite:
            if not args.up:
                raise ProblemError(f"--out: {target} exists: give another --out, --overwrite, "
                                   "or --up to run it")
            written = yaml.safe_load(target.read_text()) or {}
            if written.get("name") != f"sqpmpc-{scenario.name}":
                raise ProblemError(f"--out: {target} is the stack of {written.get('name')!r}, "
                                   f"not of {scenario.name}: give another --out or --overwrite")
            print(f"using {target} (--overwrite writes it again)", flush=True)
        else:
            _write(args, argv, out, target, scenario)
        runs = out / "runs"
        if args.up:
            if shutil.which(args.docker) is None:
                raise ProblemError(f"no {args.docker!r} on PATH: install Docker with Compose v2 "
                                   "(e.g. Debian's docker.io and docker-compose)")
            runs.mkdir(parents=True, exist_ok=True)  # the plant writes here as this user
    except (ProblemError, ScenarioError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except (OSError, yaml.YAMLError) as exc:
        print(f"{prog}: error: {args.out}: {getattr(exc, 'strerror', None) or exc}",
              file=sys.stderr)
        return 2
    if not args.up:
        print(f"run it with: {prog} --scenario {args.scenario} --out {out} --up")
        return 0
    env = dict(os.environ, SQPMPC_UID=str(os.getuid()), SQPMPC_GID=str(os.getgid()))
    controllers = [n for n in identities(scenario, args.scheme) if n != "plant"]
    status = supervise(target, controllers, args.docker, env)
    folders = sorted((p for p in runs.glob("*") if p.is_dir()), key=lambda p: p.stat().st_mtime)
    if folders:
        print(f"== outputs in {folders[-1]} (sqpmpc metrics, sqpmpc animate read it)")
    return status


if __name__ == "__main__":
    sys.exit(main())
