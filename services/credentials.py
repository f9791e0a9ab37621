"""A run's credentials: a certificate authority, one certificate per process, Zenoh configs.

``sqpmpc credentials --scenario S --run R --out DIR [--scheme decentralized|centralized]
[--host NAME] [--router] [--router-listen EP] [--no-viewer] [--valid-hours H]``

Every process of a secured run speaks Zenoh over mutual TLS with a
certificate of its own, signed by the run's certificate authority, whose
common name is its identity. Only the identities the run's processes use are
issued: ``plant``; ``robot-<id>`` (one per robot of the scenario) for the
decentralized scheme or ``central`` for the centralized one; ``router`` only
for a run through a router (``--router``); ``viewer`` (read only) unless
``--no-viewer``. The CA's private key is never written: once the folder is
made nobody can issue another certificate for the run. Each process's Zenoh
configuration (``DIR/<identity>.json5``) holds its certificate, its key, the
CA and the run's access-control rules (:func:`acl_config`): a node accepts
from a connected process (identified by the common name of its certificate)
only

- what any process of the run may send: subscriptions, liveliness
  subscriptions and queries on the run's keys (and replies on ``alive/**``);
- what that identity may publish: the plant ``plant/**`` and the token
  ``alive/plant``; robot ``<id>`` ``robot/<id>/**`` (its ``cmd``, its
  ``plan``, its addressed ``plan/<to>``) and ``alive/robot/<id>``; the central
  controller ``robot/*/cmd`` and ``alive/central``; the viewer nothing but
  its token ``alive/viewer``; the router, at its clients, what it forwards
  (it enforces these rules on what each client sends, so a client of a
  router trusts it), and at the router itself nothing: the router's key
  cannot publish through the router.

Everything else is dropped by Zenoh's ACL interceptor on ingress
(``default_permission: deny``); the plain ``tcp`` protocol is disabled, so a
process without a certificate of the run's CA cannot connect at all.
:mod:`services.launch` issues its run's credentials in memory
(:func:`issue`) and hands each process only its own (:mod:`services.handover`).
``docs/security.md`` has the threat model and the measurements.
"""

from __future__ import annotations

import argparse
import base64
import datetime
import json
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
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
    "Issued",
    "add_parser",
    "config_for",
    "identities",
    "identity_of",
    "issue",
    "main",
    "read_meta",
    "session_config",
    "write_credentials",
    "write_private",
]

CA_FILE = "ca.pem"
"""The run's CA certificate in a credentials folder."""
META_FILE = "credentials.json"
"""What a credentials folder was made for: run, scenario, identities."""
SCHEMES = ("decentralized", "centralized")
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


def identities(scenario: Scenario, scheme: str = "decentralized", router: bool = False,
               viewer: bool = False) -> list[str]:
    """The identities of a run of ``scenario`` with the ``scheme``'s controllers: only
    those its processes use (the ``router`` and the ``viewer`` only when asked)."""
    if scheme not in SCHEMES:
        raise ProblemError(f"--scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")
    names = ["plant", *(["router"] if router else []), *(["viewer"] if viewer else [])]
    if scheme == "centralized":
        names.append("central")
    else:
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


def acl_config(run: str, names: Sequence[str], me: str | None = None) -> dict[str, Any]:
    """Zenoh ``access_control`` of process ``me`` in a run whose processes are ``names``
    (module docstring).

    The ``router`` may forward: its clients accept from it what any identity may
    publish; the router itself accepts nothing but subscriptions from another holder
    of the ``router`` key (``me == "router"``), so that key cannot publish through it.
    """
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
            if me != "router":  # what it forwards from the run's processes
                rules.append({"id": "router-forward", "flows": ["ingress"],
                              "permission": "allow", "messages": _ALL,
                              "key_exprs": everything})
                own = ["router-forward"]
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


def session_config(folder: Path | None, identity: str, acl: dict[str, Any],
                   listen: Sequence[str] = (),
                   inline: tuple[bytes, bytes, bytes] | None = None) -> dict[str, Any]:
    """The Zenoh configuration of ``identity`` with the certificates in ``folder``, or
    ``inline`` (CA certificate, certificate, private key; PEM, held in the config itself).

    Only ``tls`` links are enabled; the endpoints, and the mode of a service,
    come from its command line (``listen``: the router's endpoints).
    """
    if inline is not None:
        ca, cert_pem, key_pem = (base64.b64encode(b).decode() for b in inline)
        tls: dict[str, Any] = {"root_ca_certificate_base64": ca,
                               "listen_certificate_base64": cert_pem,
                               "listen_private_key_base64": key_pem,
                               "connect_certificate_base64": cert_pem,
                               "connect_private_key_base64": key_pem}
    elif folder is not None:
        cert, key = str(folder / f"{identity}.pem"), str(folder / f"{identity}.key")
        tls = {"root_ca_certificate": str(folder / CA_FILE),
               "listen_certificate": cert, "listen_private_key": key,
               "connect_certificate": cert, "connect_private_key": key}
    else:
        raise ValueError("session_config needs a folder or inline certificates")
    conf: dict[str, Any] = {
        "mode": "router" if identity == "router" else "peer",
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {
            "protocols": ["tls"],
            "tls": {**tls, "enable_mtls": True, "verify_name_on_connect": True},
        }},
        "access_control": acl,
    }
    if listen:
        conf["listen"] = {"endpoints": list(listen)}
    return conf


def write_private(path: Path, data: bytes) -> None:
    """Write ``data`` to a new file readable by its owner only."""
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)


@dataclass(frozen=True)
class Issued:
    """A run's certificates in memory (:func:`issue`): the CA's certificate, and per
    identity its private key and certificate (PEM); ``meta`` as in :data:`META_FILE`."""

    ca: bytes
    keys: dict[str, tuple[bytes, bytes]]
    meta: dict[str, Any]

    def config(self, identity: str, listen: Sequence[str] = ()) -> dict[str, Any]:
        """``identity``'s Zenoh configuration holding its certificate and key inline (for
        :mod:`services.handover`: nothing on disk)."""
        key_pem, cert_pem = self.keys[identity]
        acl = acl_config(self.meta["run"], self.meta["identities"], identity)
        return session_config(None, identity, acl, listen, (self.ca, cert_pem, key_pem))


def issue(scenario: Scenario, run: str, names: Sequence[str], hosts: Sequence[str] = (),
          valid_hours: float = 24.0, scheme: str = "decentralized") -> Issued:
    """Make a run's CA (kept in memory only, then dropped) and one key and certificate per
    identity in ``names``, valid for ``valid_hours`` from now."""
    check_run_name(run)
    if not valid_hours > 0.0:
        raise ProblemError(f"--valid-hours must be > 0, got {valid_hours}")
    # cryptography takes about half a second to import: only the processes that make
    # certificates pay for it, not every service
    from .certificates import CertificateAuthority

    now = datetime.datetime.now(datetime.UTC)
    start, end = now - datetime.timedelta(minutes=5), now + datetime.timedelta(hours=valid_hours)
    ca = CertificateAuthority(f"sqpmpc run {run} CA", start, end)
    keys = {name: ca.issue(name, [name, *DEFAULT_HOSTS, *hosts]) for name in names}
    meta = {"run": run, "scenario": scenario.name, "scheme": scheme, "identities": list(names),
            "valid_until": end.isoformat(timespec="seconds")}
    return Issued(ca.certificate_pem(), keys, meta)


def write_credentials(out: Path, scenario: Scenario, run: str, scheme: str = "decentralized",
                      hosts: Sequence[str] = (), valid_hours: float = 24.0,
                      router_listen: Sequence[str] | None = None, viewer: bool = False,
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
        ``"decentralized"`` (robots) or ``"centralized"`` (central).
    hosts
        Host names or addresses the certificates are also valid for (besides
        the identity, ``localhost``, ``127.0.0.1`` and ``::1``).
    valid_hours
        Validity of every certificate from now.
    router_listen
        ``None``: no router (peer to peer: no ``router`` identity is issued);
        else the endpoints in the router's config.
    viewer
        Also issue the ``viewer`` identity (read only).
    folder
        Where the processes will find the files, if not ``out`` (e.g. the path
        of a shared volume in a container); the configs name files there.

    Returns
    -------
    dict
        Identity -> path of its Zenoh config in ``out``.
    """
    names = identities(scenario, scheme, router_listen is not None, viewer)
    issued = issue(scenario, run, names, hosts, valid_hours, scheme)
    out.mkdir(parents=True, exist_ok=True)
    out.chmod(0o700)
    folder = folder or out.resolve()
    write_private(out / CA_FILE, issued.ca)
    configs: dict[str, Path] = {}
    for name in names:
        key_pem, cert_pem = issued.keys[name]
        write_private(out / f"{name}.key", key_pem)
        write_private(out / f"{name}.pem", cert_pem)
        conf = session_config(folder, name, acl_config(run, names, name),
                              (router_listen or ()) if name == "router" else ())
        configs[name] = out / f"{name}.json5"
        write_private(configs[name], (json.dumps(conf, indent=2) + "\n").encode())
    write_private(out / META_FILE, (json.dumps(issued.meta, indent=2) + "\n").encode())
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


def config_for(args: argparse.Namespace, name: str) -> Path | str | None:
    """The Zenoh config of process ``name`` (liveliness name) from ``--zenoh-config``,
    ``--credentials DIR`` (a file) or ``--credentials-fd FD`` (JSON text handed over by
    :mod:`services.launch`, :mod:`services.handover`); ``None`` when none was given.

    Raises
    ------
    ProblemError
        A missing file, or credentials made for another run or without this identity.
    """
    path = getattr(args, "zenoh_config", None)
    folder = getattr(args, "credentials", None)
    fd = getattr(args, "credentials_fd", None)
    if sum(x is not None for x in (path, folder, fd)) > 1:
        raise ProblemError("give one of --zenoh-config, --credentials, --credentials-fd")
    if path is not None:
        if not Path(path).is_file():
            raise ProblemError(f"--zenoh-config {path}: no such file")
        return Path(path)
    identity = identity_of(name)
    if fd is not None:
        from .handover import received

        meta, configs = received(fd)
        where = f"--credentials-fd {fd}"
    elif folder is not None:
        meta, configs, where = read_meta(Path(folder)), None, f"--credentials {folder}"
    else:
        return None
    run = getattr(args, "run", None)
    if run is not None and meta.get("run") != run:
        raise ProblemError(f"{where} were made for run {meta.get('run')!r}, not --run {run!r}")
    if identity not in meta.get("identities", []) or (configs is not None
                                                       and identity not in configs):
        raise ProblemError(f"{where} hold no identity {identity!r} (they have "
                           f"{', '.join(configs or meta.get('identities', []))})")
    if configs is not None:
        return json.dumps(configs[identity])
    return Path(folder) / f"{identity}.json5"


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``credentials`` to the ``sqpmpc`` subcommands; its handler is :func:`main`."""
    p = subparsers.add_parser("credentials", help="write a run's CA, per-process "
                              "certificates and Zenoh configs (mTLS + access control)")
    p.add_argument("--scenario", required=True, help="TOML file or built-in name (robot ids)")
    p.add_argument("--run", required=True, help="run name the services are started with")
    p.add_argument("--out", type=Path, required=True, help="folder to write (mode 0700)")
    p.add_argument("--scheme", choices=SCHEMES, default="decentralized",
                   help="whose controllers: the robots' (default) or the central one")
    p.add_argument("--host", action="append", default=[], metavar="NAME",
                   help="a host name or address the processes connect to, added to every "
                        "certificate (repeatable; localhost and 127.0.0.1 always are)")
    p.add_argument("--router", action="store_true",
                   help="the run goes through a router: issue the 'router' identity "
                        "(implied by --router-listen; none for a peer-to-peer run)")
    p.add_argument("--router-listen", action="append", default=[], metavar="EP",
                   help="endpoint in the router's config (repeatable; default "
                        "tls/127.0.0.1:7447)")
    p.add_argument("--no-viewer", dest="viewer", action="store_false",
                   help="issue no 'viewer' identity (read only; default: issued)")
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
        router = (args.router_listen or ["tls/127.0.0.1:7447"]) if (
            args.router or args.router_listen) else None
        configs = write_credentials(args.out, scenario, args.run, args.scheme, args.host,
                                    args.valid_hours, router, args.viewer, args.folder)
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
