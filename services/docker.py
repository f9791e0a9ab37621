"""Write a Docker Compose file for a distributed run of any scenario: ``sqpmpc docker``.

``sqpmpc docker --scenario S [--scheme decentralized|centralized] [--out DIR]
[--python-router] [--t-end T] [--overwrite]`` writes ``DIR/compose.yml`` (default
``docker/<scenario>``): a one-shot ``credentials`` service (built from the repository's
``docker/Dockerfile``), the Zenoh router, the plant and one service per robot (or the
central controller), every service a client of the router over mutual TLS.

- **A volume per identity.** The credentials service issues the run's credentials for
  the scenario's identities (so the router's access-control rules are generated for this
  scenario: every robot of it, no other) and copies each identity's certificate, key and
  Zenoh config into that identity's own volume; each service mounts only its own, so
  from robot 1's container no other identity's key is readable. The router's config is
  its identity's (``router.json5``).
- **A run folder per run**: the plant writes into ``${SQPMPC_RUNS:-./runs}`` (created by
  the user who runs compose, writable by uid 1000), in a new folder named after the
  scenario and the time; no plots (``--no-plots``: ``sqpmpc metrics`` and ``sqpmpc
  animate`` read the folder).
- **Host port** ``${SQPMPC_PORT:-17447}`` on the loopback (not 7447, the port of a ROS 2
  user's own rmw_zenoh router).
- **A killed robot rejoins**: the robots restart on failure and the plant waits for
  them (``--rejoin-timeout``); the controllers and the credentials step run under
  ``sqpmpc-hold`` so that their normal end does not stop the stack.
- **Stops** within 10 s (``stop_grace_period``).

Start it with ``docker compose -f DIR/compose.yml up --build --exit-code-from plant``;
``docker compose -f DIR/compose.yml down -v`` removes the containers and the credential
volumes.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import sys
from pathlib import Path
from typing import Any

import yaml

from sqpmpc import __version__
from sqpmpc.cli.options import Parser, add_override_options
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.problem.goals import unreachable_goals
from sqpmpc.problem.scenario_file import builtin_scenario_names, load_scenario

from .credentials import identities

__all__ = ["PORT", "build_parser", "compose_file", "main"]

PROG = "services.docker"
PORT = 17447
"""Default host port of the router (not 7447: rmw_zenoh's router uses that)."""
ROOT = Path(__file__).resolve().parent.parent
RUN = "compose"


def _volume(identity: str) -> str:
    return f"id-{identity}"


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
        f"&& chown -R 1000:1000 /id/{n} && chmod 700 /id/{n}" for n in names)
    issue = (f"python -m sqpmpc credentials --scenario {scenario_in} --run {RUN} "
             f"--scheme {scheme} --router-listen tls/0.0.0.0:7447 --out /tmp/c "
             f"--folder /credentials && {copies} && rm -rf /tmp/c")
    base = {"image": "sqpmpc:latest", "pull_policy": "never", "init": True,
            "stop_grace_period": "10s"}
    held = {"entrypoint": ["sqpmpc-hold"]}
    services: dict[str, Any] = {
        "credentials": {
            **base, **held, "pull_policy": "build", "user": "0",
            "build": {"context": os.path.relpath(ROOT, out.resolve()),
                      "dockerfile": "docker/Dockerfile"},
            "volumes": [f"{_volume(n)}:/id/{n}" for n in names] + mount_scenario,
            "command": ["sh", "-c", issue],
            "healthcheck": {"test": ["CMD-SHELL",
                                     "test \"$(cat /tmp/sqpmpc-status 2>/dev/null)\" = 0"],
                            "interval": "1s", "timeout": "2s", "retries": 300},
            "restart": "no",
        },
    }
    after = {"credentials": {"condition": "service_healthy"}}
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
            **base, **held, "restart": "on-failure", "depends_on": depends,
            "volumes": [f"{_volume(name)}:/credentials:ro", *mount_scenario],
            "command": [*cmd, *common],
        }
    volumes_root = {_volume(n): {} for n in names}
    return {"name": f"sqpmpc-{scenario.name}", "services": services, "volumes": volumes_root}


_HEADER = """# Written by `sqpmpc docker {args}`: a distributed run of {scenario} ({n} robots,
# {scheme}) through a Zenoh router, mutual TLS, a credentials volume per service.
#   mkdir -p {runs} && docker compose -f {file} up --build --exit-code-from plant
#   docker compose -f {file} down -v      # the containers and the credential volumes
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
    add_override_options(parser)
    return parser


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Entry point: 0 written, 2 bad input."""
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
            raise ProblemError(f"--out: {target} exists: give another --out, or --overwrite")
        overrides = [a for flag in ("horizon", "sample_time", "t_end")
                     if getattr(args, flag) is not None
                     for a in (f"--{flag.replace('_', '-')}", repr(getattr(args, flag)))]
        data = compose_file(args.scenario, args.scheme, out, args.python_router, overrides)
        out.mkdir(parents=True, exist_ok=True)
        header = _HEADER.format(args=" ".join(argv), scenario=scenario.name,
                                n=scenario.n_robots, scheme=args.scheme, file=target,
                                runs=out / "runs", port=PORT)
        target.write_text(header + yaml.dump(data, Dumper=_Dumper, sort_keys=False, width=100))
    except (ProblemError, ScenarioError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"{prog}: error: cannot write {args.out}: {exc.strerror or exc}",
              file=sys.stderr)
        return 2
    print(f"wrote {target}: {scenario.n_robots} robots; start it with\n"
          f"  mkdir -p {out / 'runs'} && docker compose -f {target} up --build "
          "--exit-code-from plant")
    return 0


if __name__ == "__main__":
    sys.exit(main())
