"""Zenoh transport of the services: key space, session configuration, an event inbox.

Key space (version 1, one namespace per run)::

    sqpmpc/@v1/<run>/plant/state         plant -> controllers   (StateMsg, all robots)
    sqpmpc/@v1/<run>/robot/<id>/cmd      controller -> plant    (CmdMsg)
    sqpmpc/@v1/<run>/robot/<id>/plan     robot -> robots        (PlanMsg)
    sqpmpc/@v1/<run>/robot/<id>/plan/<to> robot -> robot <to>   (PlanMsg, filtered fleets)
    sqpmpc/@v1/<run>/plant/done          plant -> controllers   (DoneMsg)
    sqpmpc/@v1/<run>/alive/plant         liveliness tokens, one per process
    sqpmpc/@v1/<run>/alive/central
    sqpmpc/@v1/<run>/alive/robot/<id>

With neighbour slots a robot sends its plan, besides ``robot/<id>/plan``,
to each robot that may give it a slot at the next sample on
``robot/<id>/plan/<to>``, and subscribes to ``robot/*/plan/<own id>`` only
(:mod:`services.plans`). The plant publishes the states of all robots of a sample in one message: a
consistent snapshot, and one delivery per controller instead of ``n``.
The ``@v1`` chunk is verbatim: ``**`` does not match it, so wildcard
subscribers of another version never see these messages.

Sessions are peers (or clients of a router) with multicast scouting off and
explicit endpoints. A session given a configuration file made by
:mod:`services.credentials` speaks mutual TLS only (``tls/`` endpoints) and
enforces the run's access-control rules on what it receives. Subscribers use
callbacks that only copy the key, kind and payload into a thread-safe queue
(:class:`Bus.inbox`); all Zenoh calls happen on the main thread. zenoh-python
runs a callback on a Python thread of its own, so Zenoh's network threads
never wait for the GIL (which matters when one process hosts several robots,
:func:`services.robot.host`). Publishers use ``CongestionControl.BLOCK``
(every message must arrive); a peer's are ``express`` (no batching: a sample's
messages are on the critical path of the loop, and a peer's go to many links),
a client's are not: all of its traffic shares one link to the router, where
batching cuts the cost per message several times (measured in
``docs/fleet-services.md``).
"""

from __future__ import annotations

import json
import logging
import queue
import re
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import zenoh

from .faults import FaultInjector, kind_of_key

__all__ = [
    "KEY_ROOT",
    "Bus",
    "Event",
    "check_run_name",
    "make_config",
    "run_prefix",
]

log = logging.getLogger(__name__)

KEY_ROOT = "sqpmpc/@v1"
"""Root of the versioned key space."""
_RUN_RE = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


def check_run_name(run: str) -> str:
    """Return ``run`` if it is a valid run name (one key chunk), else raise ``ValueError``."""
    if not _RUN_RE.match(run) or run in (".", ".."):
        raise ValueError(f"run name must be 1-64 characters of A-Z a-z 0-9 _ . -, got {run!r}")
    return run


def run_prefix(run: str) -> str:
    """``sqpmpc/@v1/<run>``."""
    return f"{KEY_ROOT}/{check_run_name(run)}"


def make_config(
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    mode: str = "peer",
    config: Path | str | None = None,
    extra: Mapping[str, Any] | None = None,
) -> zenoh.Config:
    """A Zenoh configuration with multicast scouting off and explicit endpoints.

    Parameters
    ----------
    listen
        Endpoints to listen on, e.g. ``tcp/127.0.0.1:7447`` (port 0: any free port).
        A peer with none listens on ``tcp/127.0.0.1:0`` (loopback only), or on
        ``tls/127.0.0.1:0`` with a ``config`` (unless the file names endpoints).
    connect
        Endpoints to connect to (retried until they appear).
    mode
        ``"peer"``, ``"client"`` (needs a router in ``connect``) or ``"router"``.
    config
        A Zenoh configuration file to start from, e.g. a process's file made by
        :func:`services.credentials.write_credentials` (mutual TLS and access
        control), or such a configuration as JSON text (handed over by
        :mod:`services.handover`); its endpoints must then be ``tls/`` ones.
    extra
        More entries, config path -> value (e.g. :func:`services.limits.interceptors`).
    """
    if mode not in ("peer", "client", "router"):
        raise ValueError(f"zenoh mode must be peer, client or router, got {mode!r}")
    listen = list(listen)
    if config is None:
        conf = zenoh.Config()
    else:
        conf = (zenoh.Config.from_json5(config) if isinstance(config, str)
                else zenoh.Config.from_file(str(config)))
        for ep in [*listen, *connect]:
            if not ep.startswith("tls/"):
                raise ValueError(f"endpoint {ep}: a session with credentials takes tls/ "
                                 "endpoints only (mutual TLS)")
        if not listen and isinstance(json.loads(conf.get_json("listen/endpoints")), list):
            listen = json.loads(conf.get_json("listen/endpoints"))  # the file's own
    if not listen and mode != "client":
        listen = ["tcp/127.0.0.1:0" if config is None else "tls/127.0.0.1:0"]
    for path, value in (extra or {}).items():
        conf.insert_json5(path, json.dumps(value))
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if mode == "client":
        # wait for the router instead of failing at open
        conf.insert_json5("connect/timeout_ms", "-1")
    else:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    return conf


@dataclass(frozen=True, slots=True)
class Event:
    """Something received: ``kind`` is ``"put"``, ``"alive"`` or ``"gone"``."""

    kind: str
    key: str
    payload: bytes


class Bus:
    """One Zenoh session of a service with its inbox, publishers and liveliness token.

    Parameters
    ----------
    run
        Run name (namespace).
    listen, connect, mode, config, extra
        See :func:`make_config`.
    faults
        Lose or delay incoming messages (:mod:`services.faults`; tests, benchmarks).

    Attributes
    ----------
    send_failures
        Publications the session refused (e.g. it timed out on a lossy network):
        logged and counted, the loop goes on (lockstep re-asks, real time brakes).

    Notes
    -----
    Open the bus only in the process that uses it, after every fork, and close
    it (or use it as a context manager): an open session can hang interpreter exit.
    """

    def __init__(self, run: str, listen: Sequence[str] = (), connect: Sequence[str] = (),
                 mode: str = "peer", config: Path | str | None = None,
                 faults: FaultInjector | None = None,
                 extra: Mapping[str, Any] | None = None) -> None:
        self.prefix = run_prefix(run)
        self.express = mode != "client"
        self.inbox: queue.SimpleQueue[Event] = queue.SimpleQueue()
        self.faults = faults
        self.send_failures = 0
        self._released: deque[Event] = deque()
        self.secured = config is not None
        self.session = zenoh.open(make_config(listen, connect, mode, config, extra))
        self._subscribers: list[zenoh.Subscriber] = []
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._tokens: list[zenoh.LivelinessToken] = []
        self._closed = False

    # ---------------------------------------------------------------- keys
    def key(self, *parts: object) -> str:
        """``sqpmpc/@v1/<run>/<parts...>``."""
        return "/".join((self.prefix, *(str(p) for p in parts)))

    def relative(self, key: str) -> list[str] | None:
        """Chunks of ``key`` below this run's prefix, or ``None`` if it is not under it."""
        if not key.startswith(self.prefix + "/"):
            return None
        return key[len(self.prefix) + 1:].split("/")

    # ------------------------------------------------------------- receive
    def _on_sample(self, sample: zenoh.Sample) -> None:
        # runs on a Zenoh thread: copy and queue, nothing else
        self.inbox.put(Event("put" if sample.kind == zenoh.SampleKind.PUT else "delete",
                             str(sample.key_expr), sample.payload.to_bytes()))

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        self.inbox.put(Event("alive" if sample.kind == zenoh.SampleKind.PUT else "gone",
                             str(sample.key_expr), b""))

    def subscribe(self, *parts: object) -> None:
        """Subscribe to ``<prefix>/<parts>`` (wildcards allowed); samples go to the inbox."""
        self._subscribers.append(self.session.declare_subscriber(self.key(*parts),
                                                                 self._on_sample))

    def watch_liveliness(self) -> None:
        """Report every liveliness token of the run (present ones first) to the inbox."""
        self._subscribers.append(self.session.liveliness().declare_subscriber(
            self.key("alive", "**"), self._on_liveliness, history=True))

    def get(self, timeout: float) -> Event | None:
        """Next event, waiting at most ``timeout`` seconds (``None`` if none came)."""
        if self._released:
            return self._released.popleft()
        try:
            if timeout <= 0.0:
                event = self.inbox.get_nowait()
            else:
                event = self.inbox.get(timeout=timeout)
        except queue.Empty:
            return None
        if self.faults is None or event.kind != "put":
            return event
        parts = self.relative(event.key) or []
        released = self.faults.admit(kind_of_key(parts), event.payload, event)
        self._released.extend(released)  # type: ignore[arg-type]
        return self._released.popleft() if self._released else None

    # ------------------------------------------------------------- publish
    def put(self, payload: bytes, *parts: object) -> None:
        """Publish ``payload`` on ``<prefix>/<parts>`` (reliable, blocking congestion control)."""
        key = self.key(*parts)
        if self.faults is not None:
            if parts == ("plant", "state"):
                self.faults.tick(int(msgpack.unpackb(payload, raw=False)["sample"]))
            if self.faults.muted():  # services.faults 'mute': there, but silent
                return
        try:
            pub = self._publishers.get(key)
            if pub is None:
                pub = self.session.declare_publisher(
                    key, congestion_control=zenoh.CongestionControl.BLOCK, express=self.express)
                self._publishers[key] = pub
            pub.put(payload)
        except zenoh.ZError as exc:
            self.send_failures += 1
            if self.send_failures <= 10 or self.send_failures % 1000 == 0:
                log.warning("could not publish on %s (%d so far): %s", key, self.send_failures,
                            str(exc).split(" at /")[0])

    def declare_alive(self, *parts: object) -> None:
        """Declare this process's liveliness token ``<prefix>/alive/<parts>``."""
        self._tokens.append(self.session.liveliness().declare_token(self.key("alive", *parts)))

    # --------------------------------------------------------------- close
    def close(self) -> None:
        """Undeclare the token, subscribers and publishers, then close the session."""
        if self._closed:
            return
        self._closed = True
        for obj in [*self._tokens, *self._subscribers, *self._publishers.values()]:
            try:
                obj.undeclare()
            except Exception as exc:  # closing must go on whatever happens
                log.debug("undeclare failed: %r", exc)
        self._tokens.clear()
        self._subscribers.clear()
        self._publishers.clear()
        try:
            self.session.close()
        except zenoh.ZError as exc:  # e.g. "close operation timed out" on a lossy network
            log.error("the Zenoh session did not close cleanly: %s", str(exc).split(" at /")[0])

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
