"""Zenoh configs for a ROS 2 side secured with TLS and access control, as rmw_zenoh's.

``python -m services.ros2.secure --scenario S --out DIR [--domain D]
[--router-listen EP] [--host NAME]``

rmw_zenoh secures a ROS 2 network in the Zenoh router's and sessions'
configs: mutual TLS (a CA, a certificate per participant) and access control
in the router, by certificate common name, generated from SROS2 policies
(``ros2 security create_keystore``, ``ros2 security create_enclave``, then
rmw_zenoh's ``zenoh_security_tools`` ``generate_configs``; ``docs/ros2.md``).
ROS 2 is not installable here, so this module writes the equivalent configs
for the topics of an sqpmpc fleet, into ``DIR`` (mode 0700, files 0600):

- ``ca.pem``; per participant its key and certificate;
- ``ros2-router.json5``: the router (mode ``router``, TLS listen on
  ``--router-listen``, default ``tls/127.0.0.1:7447``), its access control:
  default deny; ``controller-<id>`` may publish ``<D>/robot<id>/cmd_vel/**``
  and ``<D>/robot<id>/plan/**`` and subscribe to ``<D>/robot<id>/odom/**``;
  ``base-<id>`` (the robot's own base) may publish ``<D>/robot<id>/odom/**``
  and subscribe to ``<D>/robot<id>/cmd_vel/**``; ``bases`` (a simulator of the
  whole fleet) may do so for every robot; every participant may declare and
  query graph tokens (``@ros2_lv/<D>/**``);
- ``controller-<id>.json5`` (``sqpmpc robot --ros2 --ros2-zenoh-config``),
  ``base-<id>.json5``, ``bases.json5``: client sessions with their own
  certificate, connecting to the router.

A process without a certificate of this CA cannot connect; one with another
participant's certificate cannot publish a robot's commands or odometry.
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sqpmpc.cli.options import Parser
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.problem.scenario_file import load_scenario

from ..credentials import CA_FILE, DEFAULT_HOSTS, write_private

__all__ = ["ROUTER", "build_parser", "main", "ros2_acl", "write_ros2_configs"]

ROUTER = "ros2-router"
"""The router's identity (certificate common name)."""
_GRAPH = ["liveliness_token", "liveliness_query", "declare_liveliness_subscriber"]


def _rules(name: str, domain: int, ids: Sequence[int]) -> list[tuple[str, list[str], list[str]]]:
    """``(suffix, messages, key expressions)`` a participant may send to the router."""
    own = [int(name.split("-", 1)[1])] if name.split("-", 1)[-1].isdigit() else list(ids)
    if name.startswith("controller-"):
        out = [f"{domain}/robot{i}/{t}/**" for i in own for t in ("cmd_vel", "plan")]
        inp = [f"{domain}/robot{i}/odom/**" for i in own]
    else:  # base-<id> or bases
        out = [f"{domain}/robot{i}/odom/**" for i in own]
        inp = [f"{domain}/robot{i}/cmd_vel/**" for i in own]
    return [("put", ["put", "delete"], out), ("sub", ["declare_subscriber"], inp),
            ("graph", _GRAPH, [f"@ros2_lv/{domain}/**"])]


def ros2_acl(domain: int, names: Sequence[str], ids: Sequence[int]) -> dict[str, Any]:
    """The router's ``access_control``: what each participant in ``names`` may send it."""
    rules: list[dict[str, Any]] = [
        {"id": "forward", "flows": ["egress"], "permission": "allow",
         "messages": ["put", "delete", "declare_subscriber", "query", "reply",
                      "declare_queryable", *_GRAPH],
         "key_exprs": [f"{domain}/**", f"@ros2_lv/{domain}/**"]}]
    subjects: list[dict[str, Any]] = [{"id": "anyone"}]
    policies: list[dict[str, Any]] = [{"rules": ["forward"], "subjects": ["anyone"]}]
    for name in names:
        subjects.append({"id": name, "cert_common_names": [name]})
        mine = []
        for suffix, messages, keys in _rules(name, domain, ids):
            rules.append({"id": f"{name}-{suffix}", "flows": ["ingress"], "permission": "allow",
                          "messages": messages, "key_exprs": keys})
            mine.append(f"{name}-{suffix}")
        policies.append({"rules": mine, "subjects": [name]})
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def _session(folder: Path, name: str, mode: str, endpoints: dict[str, list[str]],
             acl: dict[str, Any] | None) -> dict[str, Any]:
    cert, key = str(folder / f"{name}.pem"), str(folder / f"{name}.key")
    conf: dict[str, Any] = {
        "mode": mode,
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"protocols": ["tls"], "tls": {
            "root_ca_certificate": str(folder / CA_FILE), "listen_certificate": cert,
            "listen_private_key": key, "connect_certificate": cert,
            "connect_private_key": key, "enable_mtls": True,
            "verify_name_on_connect": True}}},
        **endpoints,
    }
    if acl is not None:
        conf["access_control"] = acl
    return conf


def write_ros2_configs(out: Path, ids: Sequence[int], domain: int = 0,
                       router_listen: str = "tls/127.0.0.1:7447", hosts: Sequence[str] = (),
                       valid_hours: float = 24.0) -> dict[str, Path]:
    """Write the CA, every participant's key, certificate and Zenoh config (module notes)
    into ``out``; returns identity -> config path."""
    if not router_listen.startswith("tls/"):
        raise ProblemError(f"--router-listen {router_listen}: a tls/ endpoint")
    from ..certificates import CertificateAuthority

    now = datetime.datetime.now(datetime.UTC)
    ca = CertificateAuthority("sqpmpc ROS 2 CA", now - datetime.timedelta(minutes=5),
                              now + datetime.timedelta(hours=valid_hours))
    names = [*(f"controller-{int(i)}" for i in ids), *(f"base-{int(i)}" for i in ids), "bases"]
    out.mkdir(parents=True, exist_ok=True)
    out.chmod(0o700)
    folder = out.resolve()
    write_private(out / CA_FILE, ca.certificate_pem())
    configs: dict[str, Path] = {}
    for name in [ROUTER, *names]:
        key_pem, cert_pem = ca.issue(name, [name, *DEFAULT_HOSTS, *hosts])
        write_private(out / f"{name}.key", key_pem)
        write_private(out / f"{name}.pem", cert_pem)
        if name == ROUTER:
            conf = _session(folder, name, "router",
                            {"listen": {"endpoints": [router_listen]}},
                            ros2_acl(domain, names, ids))
        else:
            conf = _session(folder, name, "client",
                            {"connect": {"endpoints": [router_listen]}}, None)
        configs[name] = out / f"{name}.json5"
        write_private(configs[name], (json.dumps(conf, indent=2) + "\n").encode())
    return configs


def build_parser(prog: str = "services.ros2.secure") -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.ros2.secure``."""
    p = Parser(prog=prog, description=__doc__.splitlines()[0])
    p.add_argument("--scenario", required=True, help="TOML file or built-in name (robot ids)")
    p.add_argument("--out", type=Path, required=True, help="folder to write (mode 0700)")
    p.add_argument("--domain", type=int, default=0, help="ROS domain id (default 0)")
    p.add_argument("--router-listen", default="tls/127.0.0.1:7447", metavar="EP",
                   help="the router's TLS endpoint (default tls/127.0.0.1:7447)")
    p.add_argument("--host", action="append", default=[], metavar="NAME",
                   help="a host name or address the certificates are also valid for")
    return p


def main(argv: list[str] | None = None, prog: str = "services.ros2.secure") -> int:
    """Entry point: 0, or 2 with one error line."""
    args = build_parser(prog).parse_args(argv)
    try:
        if not 0 <= args.domain <= 232:
            raise ProblemError(f"--domain: expected 0..232, got {args.domain}")
        scenario = load_scenario(args.scenario)
        configs = write_ros2_configs(args.out, [int(i) for i in scenario.ids], args.domain,
                                     args.router_listen, args.host)
    except (ScenarioError, ProblemError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {len(configs)} configs to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
