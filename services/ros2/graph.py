"""rmw_zenoh's wire format: data keys, attachments, liveliness tokens, and a node on a session.

What ROS 2's Zenoh middleware (rmw_zenoh, Jazzy) puts on the wire, from its
design notes:

- **Data key** of a topic: ``<domain>/<fully qualified name without the leading
  slash>/<DDS type name>/<type hash>``, e.g.
  ``0/robot1/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_9c45...``
  (:func:`topic_key`).
- **Payload**: the message in CDR with its encapsulation header
  (:mod:`services.ros2.msgs`).
- **Attachment** of every sample, 33 bytes little endian (:class:`Attachment`):
  ``int64`` sequence number (from 1, per publisher), ``int64`` source
  timestamp (ns since the Unix epoch), ``uint8`` GID length (16) and the
  publisher's 16-byte GID.
- **Graph**: a liveliness token per node and per endpoint (:func:`node_token`,
  :func:`endpoint_token`) under ``@ros2_lv/<domain>/<session id>/<node id>/
  <entity id>/<NN|MP|MS>/<enclave>/<namespace>/<node name>`` followed, for a
  publisher (``MP``) or subscription (``MS``), by ``/<topic>/<DDS type
  name>/<type hash>/<QoS>``; names are mangled (``/`` -> ``%``, an empty
  namespace or enclave is ``%``). ``ros2 node list`` and ``ros2 topic list``
  read these tokens.
- **QoS** in a token (:func:`qos_string`): ``<reliability>:<durability>:
  <history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:<liveliness>,<s>,<ns>``
  with default values left empty (``::,10:,:,:,,`` for reliable, volatile,
  keep last 10).

:class:`Ros2Node` declares a node and its publishers and subscriptions on a
Zenoh session (one node per session; its session id is the session's Zenoh id).
"""

from __future__ import annotations

import hashlib
import logging
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from .msgs import CdrError, dds_type_name, deserialize, serialize, type_hash, type_name_of

__all__ = [
    "ADMIN_SPACE",
    "DEFAULT_QOS",
    "Attachment",
    "Received",
    "Ros2Node",
    "Ros2Publisher",
    "check_name",
    "endpoint_token",
    "mangle",
    "node_token",
    "qos_string",
    "topic_key",
]

log = logging.getLogger(__name__)

ADMIN_SPACE = "@ros2_lv"
"""First chunk of every graph liveliness token."""


def qos_string(reliable: bool = True, transient_local: bool = False, depth: int = 10) -> str:
    """A QoS profile as rmw_zenoh writes it in tokens (defaults left empty)."""
    if depth < 0:
        raise ValueError(f"history depth must be >= 0, got {depth}")
    reliability = "" if reliable else "2"
    durability = "1" if transient_local else ""
    return f"{reliability}:{durability}:,{depth}:,:,:,,"


DEFAULT_QOS = qos_string()
"""Reliable, volatile, keep last 10 (``rmw_qos_profile_default``)."""


def check_name(name: str, what: str) -> str:
    """``name`` if it is a valid absolute ROS 2 name (``/a/b_1``), else ``ValueError``."""
    parts = name.split("/")
    if (not name.startswith("/") or name != "/" and name.endswith("/")
            or any(not p or not (p[0].isalpha() or p[0] == "_")
                   or not all(c.isalnum() or c == "_" for c in p)
                   for p in parts[1:] if name != "/")):
        raise ValueError(f"{what} must be an absolute ROS 2 name such as /robot1 (letters, "
                         f"digits, _; no empty or leading-digit parts), got {name!r}")
    return name


def mangle(name: str) -> str:
    """A name as one key chunk: ``/`` -> ``%`` (empty or ``/`` -> ``%``)."""
    return "%" if name in ("", "/") else name.replace("/", "%")


def topic_key(domain: int, topic: str, type_name: str) -> str:
    """The data key of ``topic`` (absolute) of type ``type_name`` in ``domain``."""
    return f"{int(domain)}/{topic.lstrip('/')}/{dds_type_name(type_name)}/{type_hash(type_name)}"


def node_token(domain: int, zid: str, node_id: int, namespace: str, name: str,
               enclave: str = "") -> str:
    """The liveliness token of a node."""
    return (f"{ADMIN_SPACE}/{int(domain)}/{zid}/{node_id}/{node_id}/NN/{mangle(enclave)}/"
            f"{mangle(namespace)}/{name}")


def endpoint_token(domain: int, zid: str, node_id: int, entity_id: int, kind: str,
                   namespace: str, name: str, topic: str, type_name: str,
                   qos: str = DEFAULT_QOS, enclave: str = "") -> str:
    """The liveliness token of a publisher (``kind="MP"``) or subscription (``"MS"``)."""
    if kind not in ("MP", "MS"):
        raise ValueError(f"endpoint kind must be MP or MS, got {kind!r}")
    return (f"{ADMIN_SPACE}/{int(domain)}/{zid}/{node_id}/{entity_id}/{kind}/"
            f"{mangle(enclave)}/{mangle(namespace)}/{name}/{mangle(topic)}/"
            f"{dds_type_name(type_name)}/{type_hash(type_name)}/{qos}")


@dataclass(frozen=True, slots=True)
class Attachment:
    """The attachment of a sample: sequence number, source timestamp (ns), GID (16 bytes)."""

    sequence: int
    timestamp_ns: int
    gid: bytes

    SIZE = 33

    def __post_init__(self) -> None:
        if len(self.gid) != 16:
            raise ValueError(f"a GID has 16 bytes, got {len(self.gid)}")

    def to_bytes(self) -> bytes:
        """The 33 bytes on the wire."""
        return struct.pack("<qqB", self.sequence, self.timestamp_ns, 16) + bytes(self.gid)

    @staticmethod
    def from_bytes(data: bytes) -> Attachment:
        """Parse an attachment (``ValueError`` if it is not 33 bytes with a 16-byte GID)."""
        if len(data) != Attachment.SIZE or data[16] != 16:
            raise ValueError(f"an rmw_zenoh attachment is {Attachment.SIZE} bytes with a "
                             f"16-byte GID, got {len(data)} bytes")
        seq, ts = struct.unpack_from("<qq", data, 0)
        return Attachment(seq, ts, bytes(data[17:]))


@dataclass(frozen=True, slots=True)
class Received:
    """A message taken from a subscription, with its attachment and arrival time (Unix s)."""

    msg: Any
    attachment: Attachment | None
    arrival: float


class Ros2Publisher:
    """A ROS 2 publisher of one topic (made by :meth:`Ros2Node.publisher`)."""

    def __init__(self, node: Ros2Node, topic: str, type_name: str, entity_id: int,
                 qos: str) -> None:
        self.topic = topic
        self.type_name = type_name
        self.key = topic_key(node.domain, topic, type_name)
        self.token_key = endpoint_token(node.domain, node.zid, node.node_id, entity_id, "MP",
                                        node.namespace, node.name, topic, type_name, qos)
        self.gid = hashlib.sha256(self.token_key.encode()).digest()[:16]
        self.sequence = 0
        self.failures = 0
        self._pub = node.session.declare_publisher(
            self.key, congestion_control=zenoh.CongestionControl.BLOCK, express=True)
        self._token = node.session.liveliness().declare_token(self.token_key)

    def publish(self, msg: object) -> None:
        """Serialize and send ``msg`` with the next attachment (counted, logged on failure)."""
        if type_name_of(msg) != self.type_name:
            raise TypeError(f"{self.topic} carries {self.type_name}, got {type_name_of(msg)}")
        self.sequence += 1
        att = Attachment(self.sequence, time.time_ns(), self.gid)
        try:
            self._pub.put(serialize(msg), encoding=zenoh.Encoding("application/cdr"),
                          attachment=att.to_bytes())
        except zenoh.ZError as exc:
            self.failures += 1
            if self.failures <= 10:
                log.warning("could not publish on %s: %s", self.topic, str(exc).split(" at /")[0])

    def close(self) -> None:
        """Undeclare the token and the publisher."""
        for obj in (self._token, self._pub):
            try:
                obj.undeclare()
            except Exception as exc:  # closing goes on whatever happens
                log.debug("undeclare failed: %r", exc)


class Ros2Node:
    """A ROS 2 node on a Zenoh session, in rmw_zenoh's format.

    Parameters
    ----------
    session
        An open Zenoh session (kept open by the caller).
    name
        Node name (letters, digits, ``_``).
    namespace
        Absolute namespace, e.g. ``/robot1`` (``/``: none).
    domain
        ROS domain id (``ROS_DOMAIN_ID``), 0..232.

    Attributes
    ----------
    invalid
        Samples received that were not a CDR message of the topic's type (dropped).
    """

    def __init__(self, session: zenoh.Session, name: str, namespace: str = "/",
                 domain: int = 0) -> None:
        if not name or not (name[0].isalpha() or name[0] == "_") or not all(
                c.isalnum() or c == "_" for c in name):
            raise ValueError(f"node name must be letters, digits and _, got {name!r}")
        check_name(namespace, "namespace")
        if not 0 <= int(domain) <= 232:
            raise ValueError(f"ROS domain id must be 0..232, got {domain}")
        self.session = session
        self.name = name
        self.namespace = namespace
        self.domain = int(domain)
        self.zid = str(session.info.zid())
        self.node_id = 0
        self._next_entity = 1
        self.invalid = 0
        self._lock = threading.Lock()
        self._endpoints: list[Any] = []
        self._token = session.liveliness().declare_token(
            node_token(self.domain, self.zid, self.node_id, namespace, name))

    def resolve(self, topic: str) -> str:
        """The fully qualified name of ``topic`` (relative names are in the namespace)."""
        full = topic if topic.startswith("/") else (
            f"{self.namespace.rstrip('/')}/{topic}")
        return check_name(full, "topic")

    def _entity(self) -> int:
        with self._lock:
            self._next_entity += 1
            return self._next_entity - 1

    def publisher(self, topic: str, type_name: str, qos: str = DEFAULT_QOS) -> Ros2Publisher:
        """Declare a publisher of ``topic`` (relative to the namespace unless absolute)."""
        pub = Ros2Publisher(self, self.resolve(topic), type_name, self._entity(), qos)
        self._endpoints.append(pub)
        return pub

    def subscribe(self, topic: str, type_name: str, callback: Callable[[Received], None],
                  qos: str = DEFAULT_QOS) -> str:
        """Subscribe to ``topic``; ``callback`` gets each valid message (on a Zenoh thread).

        Returns the data key subscribed to. A sample that is not a CDR message
        of ``type_name`` is counted in :attr:`invalid` and dropped.
        """
        full = self.resolve(topic)
        key = topic_key(self.domain, full, type_name)

        def on_sample(sample: zenoh.Sample) -> None:
            arrival = time.time()
            try:
                msg = deserialize(sample.payload.to_bytes(), type_name)
            except CdrError as exc:
                with self._lock:
                    self.invalid += 1
                    if self.invalid <= 10:
                        log.warning("dropped an invalid %s on %s: %s", type_name, full, exc)
                return
            att = None
            if sample.attachment is not None:
                try:
                    att = Attachment.from_bytes(sample.attachment.to_bytes())
                except ValueError:
                    att = None
            callback(Received(msg, att, arrival))

        self._endpoints.append(self.session.declare_subscriber(key, on_sample))
        self._endpoints.append(self.session.liveliness().declare_token(endpoint_token(
            self.domain, self.zid, self.node_id, self._entity(), "MS", self.namespace,
            self.name, full, type_name, qos)))
        return key

    def close(self) -> None:
        """Undeclare every endpoint and the node's token (the session stays open)."""
        for obj in [*self._endpoints, self._token]:
            try:
                if isinstance(obj, Ros2Publisher):
                    obj.close()
                else:
                    obj.undeclare()
            except Exception as exc:  # closing goes on whatever happens
                log.debug("undeclare failed: %r", exc)
        self._endpoints.clear()
