"""A run's credentials: a certificate authority, one certificate per process, Zenoh configs.

``sqpmpc credentials --scenario S --run R --out DIR [--scheme ...] [--host NAME]
[--router-listen EP] [--valid-hours H]``

Every process of a secured run speaks Zenoh over mutual TLS with a
certificate of its own, signed by the run's certificate authority, whose
common name is its identity: ``plant``, ``central``, ``robot-<id>`` (one per
robot of the scenario), ``router`` and ``viewer``. The CA's private key is
never written: once the folder is made nobody can issue another certificate
for the run. Each process's Zenoh configuration (``DIR/<identity>.json5``)
holds its certificate, its key, the CA and the run's access-control rules
(:func:`acl_config`), the same in every process: a node accepts from a
connected process (identified by the common name of its certificate) only

- what any process of the run may send: subscriptions, liveliness
  subscriptions and queries on the run's keys (and replies on ``alive/**``);
- what that identity may publish: the plant ``plant/**`` and the token
  ``alive/plant``; robot ``<id>`` ``robot/<id>/**`` (its ``cmd``, its
  ``plan``, its addressed ``plan/<to>``) and ``alive/robot/<id>``; the central
  controller ``robot/*/cmd`` and ``alive/central``; the viewer nothing but
  its token ``alive/viewer``; the router everything on the run's keys (it
  enforces the same rules on what it receives, so a client of a router
  trusts it).

Everything else is dropped by Zenoh's ACL interceptor on ingress
(``default_permission: deny``); the plain ``tcp`` protocol is disabled, so a
process without a certificate of the run's CA cannot connect at all.
``docs/security.md`` has the threat model and the measurements.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sqpmpc.cli.options import positive_float
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import load_scenario

from .transport import check_run_name, run_prefix

__all__ = [
    "CA_FILE",
    "META_FILE",
    "SCHEMES",
    "acl_config",
    "add_parser",
    "config_for",
    "identities",
    "identity_of",
    "main",
    "read_meta",
    "session_config",
    "write_credentials",
]

CA_FILE = "ca.pem"
"""The run's CA certificate in a credentials folder."""
META_FILE = "credentials.json"
"""What a credentials folder was made for: run, scenario, identities."""
SCHEMES = ("decentralized", "centralized", "both")
"""Which controllers a run's credentials are made for."""
DEFAULT_HOSTS = ("localhost", "127.0.0.1", "::1")
"""Names every certificate is valid for besides its identity (``verify_name_on_connect``)."""
_READ = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]
_ALL = ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
        "liveliness_token", "liveliness_query", "declare_liveliness_subscriber"]


def identity_of(name: str) -> str:
    """The identity (certificate common name) of a process by its liveliness name:
    ``"robot/3"`` -> ``"robot-3"``, ``"plant"`` -> ``"plant"``."""
    return name.replace("/", "-")


def identities(scenario: Scenario, scheme: str = "both") -> list[str]:
    """Every identity of a run of ``scenario`` with the ``scheme``'s controllers."""
    if scheme not in SCHEMES:
        raise ProblemError(f"--scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")
    names = ["plant", "router", "viewer"]
    if scheme in ("centralized", "both"):
        names.append("central")
    if scheme in ("decentralized", "both"):
        names += [f"robot-{int(i)}" for i in scenario.ids]
    return names


def _may_publish(identity: str, prefix: str) -> tuple[list[str], list[str]]:
    """(keys ``identity`` may put or delete, its liveliness tokens)."""
    if identity == "plant":
        return [f"{prefix}/plant/**"], [f"{prefix}/alive/plant"]
    if identity == "central":
        return [f"{prefix}/robot/*/cmd"], [f"{prefix}/alive/central"]
    if identity == "viewer":
        return [], [f"{prefix}/alive/viewer/**"]
    if identity.startswith("robot-"):
        rid = identity.split("-", 1)[1]
        return [f"{prefix}/robot/{rid}/**"], [f"{prefix}/alive/robot/{rid}"]
    raise ProblemError(f"unknown identity {identity!r}")


def acl_config(run: str, names: Sequence[str]) -> dict[str, Any]:
    """Zenoh ``access_control`` of a run whose processes are ``names`` (module docstring)."""
    prefix = run_prefix(run)
    everything = [f"{prefix}/**"]
    rules: list[dict[str, Any]] = [
        {"id": "send", "flows": ["egress"], "permission": "allow", "messages": _ALL,
         "key_exprs": everything},
        {"id": "read", "flows": ["ingress"], "permission": "allow", "messages": _READ,
         "key_exprs": everything},
        {"id": "reply-alive", "flows": ["ingress"], "permission": "allow",
         "messages": ["reply"], "key_exprs": [f"{prefix}/alive/**"]},
    ]
    subjects: list[dict[str, Any]] = [{"id": "anyone"}]
    policies: list[dict[str, Any]] = [{"rules": ["send"], "subjects": ["anyone"]}]
    for name in names:
        subjects.append({"id": name, "cert_common_names": [name]})
        own = ["read", "reply-alive"]
        if name == "router":
            rules.append({"id": "router-all", "flows": ["ingress"], "permission": "allow",
                          "messages": _ALL, "key_exprs": everything})
            own = ["router-all"]
        else:
            keys, tokens = _may_publish(name, prefix)
            if keys:
                rules.append({"id": f"{name}-put", "flows": ["ingress"], "permission": "allow",
                              "messages": ["put", "delete"], "key_exprs": keys})
                own.append(f"{name}-put")
            rules.append({"id": f"{name}-token", "flows": ["ingress"], "permission": "allow",
                          "messages": ["liveliness_token"], "key_exprs": tokens})
            own.append(f"{name}-token")
        policies.append({"rules": own, "subjects": [name]})
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def session_config(folder: Path, identity: str, acl: dict[str, Any],
                   listen: Sequence[str] = ()) -> dict[str, Any]:
    """The Zenoh configuration of ``identity`` with the certificates in ``folder``.

    Only ``tls`` links are enabled; the endpoints, and the mode of a service,
    come from its command line (``listen``: the router's endpoints).
    """
    cert, key = str(folder / f"{identity}.pem"), str(folder / f"{identity}.key")
    conf: dict[str, Any] = {
        "mode": "router" if identity == "router" else "peer",
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {
            "protocols": ["tls"],
            "tls": {"root_ca_certificate": str(folder / CA_FILE),
                    "enable_mtls": True,
                    "listen_certificate": cert, "listen_private_key": key,
                    "connect_certificate": cert, "connect_private_key": key,
                    "verify_name_on_connect": True},
        }},
        "access_control": acl,
    }
    if listen:
        conf["listen"] = {"endpoints": list(listen)}
    return conf


def _write_private(path: Path, data: bytes) -> None:
    """Write ``data`` to a new file readable by its owner only."""
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)


def write_credentials(out: Path, scenario: Scenario, run: str, scheme: str = "both",
                      hosts: Sequence[str] = (), valid_hours: float = 24.0,
                      router_listen: Sequence[str] = ("tls/127.0.0.1:7447",),
                      folder: Path | None = None) -> dict[str, Path]:
    """Write a run's CA certificate, per-process certificates, keys and Zenoh configs.

    Parameters
    ----------
    out
        Folder to write (created with mode 0700; files 0600).
    scenario
        The run's scenario (its robot ids).
    run
        The run name: the rules cover the keys ``sqpmpc/@v1/<run>/...`` only.
    scheme
        ``"decentralized"`` (robots), ``"centralized"`` (central) or ``"both"``.
    hosts
        Host names or addresses the certificates are also valid for (besides
        the identity, ``localhost``, ``127.0.0.1`` and ``::1``).
    valid_hours
        Validity of every certificate from now.
    router_listen
        Endpoints in the router's config.
    folder
        Where the processes will find the files, if not ``out`` (e.g. the path
        of a shared volume in a container); the configs name files there.

    Returns
    -------
    dict
        Identity -> path of its Zenoh config in ``out``.
    """
    check_run_name(run)
    if not valid_hours > 0.0:
        raise ProblemError(f"--valid-hours must be > 0, got {valid_hours}")
    names = identities(scenario, scheme)
    out.mkdir(parents=True, exist_ok=True)
    out.chmod(0o700)
    folder = folder or out.resolve()
    # cryptography takes about half a second to import: only the command that makes
    # certificates pays for it, not every service
    from .certificates import CertificateAuthority

    now = datetime.datetime.now(datetime.UTC)
    start, end = now - datetime.timedelta(minutes=5), now + datetime.timedelta(hours=valid_hours)
    ca = CertificateAuthority(f"sqpmpc run {run} CA", start, end)
    _write_private(out / CA_FILE, ca.certificate_pem())
    acl = acl_config(run, names)
    configs: dict[str, Path] = {}
    for name in names:
        key_pem, cert_pem = ca.issue(name, [name, *DEFAULT_HOSTS, *hosts])
        _write_private(out / f"{name}.key", key_pem)
        _write_private(out / f"{name}.pem", cert_pem)
        conf = session_config(folder, name, acl, router_listen if name == "router" else ())
        configs[name] = out / f"{name}.json5"
        _write_private(configs[name], (json.dumps(conf, indent=2) + "\n").encode())
    meta = {"run": run, "scenario": scenario.name, "scheme": scheme, "identities": names,
            "valid_until": end.isoformat(timespec="seconds")}
    _write_private(out / META_FILE, (json.dumps(meta, indent=2) + "\n").encode())
    return configs


def read_meta(folder: Path) -> dict[str, Any]:
    """What a credentials folder was made for (its ``META_FILE``: run, scenario, identities).

    Raises
    ------
    ProblemError
        The file is missing or not a JSON object.
    """
    try:
        meta = json.loads((Path(folder) / META_FILE).read_text())
    except (OSError, ValueError) as exc:
        raise ProblemError(f"--credentials {folder}: cannot read {META_FILE} ({exc}); make "
                           "the folder with 'sqpmpc credentials'") from exc
    if not isinstance(meta, dict):
        raise ProblemError(f"--credentials {folder}: {META_FILE} is not a JSON object; make "
                           "the folder with 'sqpmpc credentials'")
    return meta


def config_for(args: argparse.Namespace, name: str) -> Path | None:
    """The Zenoh config file of process ``name`` (liveliness name) from ``--zenoh-config``
    or ``--credentials DIR``; ``None`` when neither was given.

    Raises
    ------
    ProblemError
        A missing file, or credentials made for another run.
    """
    path = getattr(args, "zenoh_config", None)
    folder = getattr(args, "credentials", None)
    if path is not None and folder is not None:
        raise ProblemError("give --zenoh-config or --credentials, not both")
    if path is not None:
        if not Path(path).is_file():
            raise ProblemError(f"--zenoh-config {path}: no such file")
        return Path(path)
    if folder is None:
        return None
    folder = Path(folder)
    meta = read_meta(folder)
    run = getattr(args, "run", None)
    if run is not None and meta.get("run") != run:
        raise ProblemError(f"--credentials {folder} were made for run {meta.get('run')!r}, "
                           f"not --run {run!r}")
    identity = identity_of(name)
    if identity not in meta.get("identities", []):
        raise ProblemError(f"--credentials {folder} hold no identity {identity!r} (they have "
                           f"{', '.join(meta.get('identities', []))})")
    return folder / f"{identity}.json5"


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``credentials`` to the ``sqpmpc`` subcommands; its handler is :func:`main`."""
    p = subparsers.add_parser("credentials", help="write a run's CA, per-process "
                              "certificates and Zenoh configs (mTLS + access control)")
    p.add_argument("--scenario", required=True, help="TOML file or built-in name (robot ids)")
    p.add_argument("--run", required=True, help="run name the services are started with")
    p.add_argument("--out", type=Path, required=True, help="folder to write (mode 0700)")
    p.add_argument("--scheme", choices=SCHEMES, default="both",
                   help="identities of which controllers: robots, central or both (default)")
    p.add_argument("--host", action="append", default=[], metavar="NAME",
                   help="a host name or address the processes connect to, added to every "
                        "certificate (repeatable; localhost and 127.0.0.1 always are)")
    p.add_argument("--router-listen", action="append", default=[], metavar="EP",
                   help="endpoint in the router's config (repeatable; default "
                        "tls/127.0.0.1:7447)")
    p.add_argument("--valid-hours", type=positive_float, default=24.0,
                   help="validity of the certificates, hours (default 24)")
    p.add_argument("--folder", type=Path, default=None,
                   help="where the processes will find the files if not --out (e.g. a "
                        "volume's mount point in a container)")
    p.set_defaults(handler=main)
    return p


def main(args: argparse.Namespace) -> int:
    """``sqpmpc credentials``: write the folder, or refuse with one message (status 2)."""
    try:
        scenario = load_scenario(args.scenario)
        check_run_name(args.run)
        configs = write_credentials(args.out, scenario, args.run, args.scheme, args.host,
                                    args.valid_hours,
                                    args.router_listen or ["tls/127.0.0.1:7447"], args.folder)
    except (ScenarioError, ProblemError, ValueError) as exc:
        print(f"sqpmpc credentials: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"sqpmpc credentials: error: cannot write {args.out}: {exc.strerror or exc}",
              file=sys.stderr)
        return 2
    print(f"wrote {args.out}: CA and {len(configs)} identities "
          f"({', '.join(configs)}) for run {args.run!r}")
    return 0
