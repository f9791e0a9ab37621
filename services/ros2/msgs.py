"""ROS 2 messages the robot service speaks, their type hashes (RIHS01) and CDR encoding.

Each message type is described once, as ROS 2 Jazzy's ``.msg`` files define it
(:data:`DEFINITIONS`: field names and types), and everything follows from that
description:

- the type hash (:func:`type_hash`): REP 2011's ``RIHS01``, the SHA-256 of the
  JSON of the type description (the type and every type it refers to, fields
  with ``type_id``, ``capacity``, ``string_capacity``, ``nested_type_name``;
  referenced types sorted by name), as ``rosidl`` computes it at build time;
- the DDS type name (:func:`dds_type_name`), e.g. ``geometry_msgs::msg::dds_::Twist_``;
- the CDR bytes (:func:`serialize`, :func:`deserialize`): plain CDR (XCDR1),
  little endian, with the 4-byte encapsulation header ``00 01 00 00``; every
  primitive aligned to its size from the end of the header, strings as a
  ``uint32`` length (with the terminating NUL) and the bytes, sequences as a
  ``uint32`` count and the elements.

Messages are frozen dataclasses (:class:`Twist`, :class:`Odometry`, ...) with
the field names of the ``.msg`` files; nested messages are dataclasses too.
Only what the robot service needs is here (Odometry, Twist, TwistStamped,
Path and what they contain).
"""

from __future__ import annotations

import hashlib
import json
import math
import struct
from dataclasses import dataclass, field, fields
from typing import Any

__all__ = [
    "DEFINITIONS",
    "CdrError",
    "Header",
    "Odometry",
    "Path",
    "Point",
    "Pose",
    "PoseStamped",
    "PoseWithCovariance",
    "Quaternion",
    "Time",
    "Twist",
    "TwistStamped",
    "TwistWithCovariance",
    "Vector3",
    "dds_type_name",
    "deserialize",
    "serialize",
    "type_hash",
    "type_name_of",
    "yaw_quaternion",
    "quaternion_yaw",
]

DEFINITIONS: dict[str, tuple[tuple[str, str], ...]] = {
    "builtin_interfaces/msg/Time": (("sec", "int32"), ("nanosec", "uint32")),
    "std_msgs/msg/Header": (("stamp", "builtin_interfaces/msg/Time"), ("frame_id", "string")),
    "geometry_msgs/msg/Vector3": (("x", "float64"), ("y", "float64"), ("z", "float64")),
    "geometry_msgs/msg/Point": (("x", "float64"), ("y", "float64"), ("z", "float64")),
    "geometry_msgs/msg/Quaternion": (("x", "float64"), ("y", "float64"), ("z", "float64"),
                                     ("w", "float64")),
    "geometry_msgs/msg/Pose": (("position", "geometry_msgs/msg/Point"),
                               ("orientation", "geometry_msgs/msg/Quaternion")),
    "geometry_msgs/msg/PoseStamped": (("header", "std_msgs/msg/Header"),
                                      ("pose", "geometry_msgs/msg/Pose")),
    "geometry_msgs/msg/PoseWithCovariance": (("pose", "geometry_msgs/msg/Pose"),
                                             ("covariance", "float64[36]")),
    "geometry_msgs/msg/Twist": (("linear", "geometry_msgs/msg/Vector3"),
                                ("angular", "geometry_msgs/msg/Vector3")),
    "geometry_msgs/msg/TwistWithCovariance": (("twist", "geometry_msgs/msg/Twist"),
                                              ("covariance", "float64[36]")),
    "geometry_msgs/msg/TwistStamped": (("header", "std_msgs/msg/Header"),
                                       ("twist", "geometry_msgs/msg/Twist")),
    "nav_msgs/msg/Odometry": (("header", "std_msgs/msg/Header"), ("child_frame_id", "string"),
                              ("pose", "geometry_msgs/msg/PoseWithCovariance"),
                              ("twist", "geometry_msgs/msg/TwistWithCovariance")),
    "nav_msgs/msg/Path": (("header", "std_msgs/msg/Header"),
                          ("poses", "geometry_msgs/msg/PoseStamped[]")),
}
"""Fields of each type as in ROS 2 Jazzy's ``.msg`` files (constants and comments left out:
they are not part of the type description)."""

# type_description_interfaces/msg/FieldType ids
_TYPE_IDS = {"int8": 2, "uint8": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7,
             "int64": 8, "uint64": 9, "float32": 10, "float64": 11, "char": 13,
             "bool": 15, "byte": 16, "string": 17}
_NESTED, _ARRAY, _BOUNDED_SEQ, _SEQ = 1, 48, 96, 144
_PRIMITIVES = {"int8": "b", "uint8": "B", "int16": "h", "uint16": "H", "int32": "i",
               "uint32": "I", "int64": "q", "uint64": "Q", "float32": "f", "float64": "d",
               "char": "B", "bool": "?", "byte": "B"}
_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR_LE, no options


class CdrError(ValueError):
    """Bytes that are not a CDR message of the expected type."""


def _parse(spec: str) -> tuple[str, str, int]:
    """``(base type, "single" | "array" | "sequence", length)`` of a field type."""
    if spec.endswith("[]"):
        return spec[:-2], "sequence", 0
    if spec.endswith("]"):
        base, _, n = spec[:-1].partition("[")
        return base, "array", int(n)
    return spec, "single", 0


def dds_type_name(name: str) -> str:
    """``pkg/msg/Type`` -> ``pkg::msg::dds_::Type_`` (rmw_zenoh's key and token chunk)."""
    pkg, kind, typ = _split(name)
    return f"{pkg}::{kind}::dds_::{typ}_"


def _split(name: str) -> tuple[str, str, str]:
    parts = name.split("/")
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"a ROS 2 type name is pkg/msg/Type, got {name!r}")
    return parts[0], parts[1], parts[2]


def _description(name: str) -> dict[str, Any]:
    if name not in DEFINITIONS:
        raise ValueError(f"unknown message type {name!r}; known: {', '.join(DEFINITIONS)}")
    out = []
    for fname, spec in DEFINITIONS[name]:
        base, shape, n = _parse(spec)
        offset = {"single": 0, "array": _ARRAY, "sequence": _SEQ}[shape]
        nested = "" if base in _TYPE_IDS else base
        out.append({"name": fname, "type": {
            "type_id": offset + (_NESTED if nested else _TYPE_IDS[base]),
            "capacity": n, "string_capacity": 0, "nested_type_name": nested}})
    return {"type_name": name, "fields": out}


def _referenced(name: str, seen: set[str]) -> None:
    for _, spec in DEFINITIONS[name]:
        base = _parse(spec)[0]
        if base not in _TYPE_IDS and base not in seen:
            seen.add(base)
            _referenced(base, seen)


def type_hash(name: str) -> str:
    """The ``RIHS01_<sha256>`` type hash of ``name`` (REP 2011, version 1)."""
    if name not in DEFINITIONS:
        raise ValueError(f"unknown message type {name!r}; known: {', '.join(DEFINITIONS)}")
    refs: set[str] = set()
    _referenced(name, refs)
    body = {"type_description": _description(name),
            "referenced_type_descriptions": [_description(r) for r in sorted(refs)]}
    return "RIHS01_" + hashlib.sha256(json.dumps(body).encode()).hexdigest()


# ----------------------------------------------------------------------------- messages
@dataclass(frozen=True, slots=True)
class Time:
    """``builtin_interfaces/msg/Time``."""

    sec: int = 0
    nanosec: int = 0

    @staticmethod
    def from_seconds(t: float) -> Time:
        """The time ``t`` (Unix s) as seconds and nanoseconds."""
        ns = int(round(t * 1e9))
        return Time(ns // 1_000_000_000, ns % 1_000_000_000)

    def seconds(self) -> float:
        """This time in seconds."""
        return self.sec + 1e-9 * self.nanosec


@dataclass(frozen=True, slots=True)
class Header:
    """``std_msgs/msg/Header``."""

    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass(frozen=True, slots=True)
class Vector3:
    """``geometry_msgs/msg/Vector3``."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass(frozen=True, slots=True)
class Point:
    """``geometry_msgs/msg/Point``."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass(frozen=True, slots=True)
class Quaternion:
    """``geometry_msgs/msg/Quaternion`` (default: the identity)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


@dataclass(frozen=True, slots=True)
class Pose:
    """``geometry_msgs/msg/Pose``."""

    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass(frozen=True, slots=True)
class PoseStamped:
    """``geometry_msgs/msg/PoseStamped``."""

    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


_ZERO36 = (0.0,) * 36


@dataclass(frozen=True, slots=True)
class PoseWithCovariance:
    """``geometry_msgs/msg/PoseWithCovariance`` (``covariance``: 36 numbers)."""

    pose: Pose = field(default_factory=Pose)
    covariance: tuple[float, ...] = _ZERO36


@dataclass(frozen=True, slots=True)
class Twist:
    """``geometry_msgs/msg/Twist``."""

    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass(frozen=True, slots=True)
class TwistWithCovariance:
    """``geometry_msgs/msg/TwistWithCovariance`` (``covariance``: 36 numbers)."""

    twist: Twist = field(default_factory=Twist)
    covariance: tuple[float, ...] = _ZERO36


@dataclass(frozen=True, slots=True)
class TwistStamped:
    """``geometry_msgs/msg/TwistStamped``."""

    header: Header = field(default_factory=Header)
    twist: Twist = field(default_factory=Twist)


@dataclass(frozen=True, slots=True)
class Odometry:
    """``nav_msgs/msg/Odometry`` (the twist is in the ``child_frame_id`` frame)."""

    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass(frozen=True, slots=True)
class Path:
    """``nav_msgs/msg/Path``."""

    header: Header = field(default_factory=Header)
    poses: tuple[PoseStamped, ...] = ()


_CLASSES: dict[str, type] = {
    "builtin_interfaces/msg/Time": Time, "std_msgs/msg/Header": Header,
    "geometry_msgs/msg/Vector3": Vector3, "geometry_msgs/msg/Point": Point,
    "geometry_msgs/msg/Quaternion": Quaternion, "geometry_msgs/msg/Pose": Pose,
    "geometry_msgs/msg/PoseStamped": PoseStamped,
    "geometry_msgs/msg/PoseWithCovariance": PoseWithCovariance,
    "geometry_msgs/msg/Twist": Twist, "geometry_msgs/msg/TwistWithCovariance": TwistWithCovariance,
    "geometry_msgs/msg/TwistStamped": TwistStamped, "nav_msgs/msg/Odometry": Odometry,
    "nav_msgs/msg/Path": Path,
}
_NAMES = {cls: name for name, cls in _CLASSES.items()}


def type_name_of(msg: object) -> str:
    """The ROS 2 type name of a message object, e.g. ``nav_msgs/msg/Odometry``."""
    try:
        return _NAMES[type(msg)]
    except KeyError:
        raise TypeError(f"not a ROS 2 message of this module: {type(msg).__name__}") from None


def yaw_quaternion(psi: float) -> Quaternion:
    """The rotation by ``psi`` about z."""
    return Quaternion(0.0, 0.0, math.sin(0.5 * psi), math.cos(0.5 * psi))


def quaternion_yaw(q: Quaternion) -> float:
    """The heading (rotation about z) of ``q``."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


# ----------------------------------------------------------------------------- CDR
class _Writer:
    def __init__(self) -> None:
        self.buf = bytearray()

    def align(self, n: int) -> None:
        self.buf.extend(b"\x00" * (-len(self.buf) % n))

    def prim(self, typ: str, value: Any) -> None:
        code = _PRIMITIVES[typ]
        size = struct.calcsize(code)
        self.align(size)
        self.buf.extend(struct.pack("<" + code, value))

    def string(self, value: str) -> None:
        data = value.encode()
        if b"\x00" in data:
            raise CdrError("a CDR string cannot hold NUL characters")
        self.prim("uint32", len(data) + 1)
        self.buf.extend(data + b"\x00")


class _Reader:
    def __init__(self, data: bytes) -> None:
        self.data = data
        self.pos = 0

    def prim(self, typ: str) -> Any:
        code = _PRIMITIVES[typ]
        size = struct.calcsize(code)
        self.pos += -self.pos % size
        if self.pos + size > len(self.data):
            raise CdrError(f"truncated at byte {self.pos} reading {typ}")
        (value,) = struct.unpack_from("<" + code, self.data, self.pos)
        self.pos += size
        return value

    def string(self) -> str:
        n = self.prim("uint32")
        if n < 1 or self.pos + n > len(self.data) or self.data[self.pos + n - 1] != 0:
            raise CdrError(f"bad string of {n} bytes at byte {self.pos}")
        text = self.data[self.pos:self.pos + n - 1]
        self.pos += n
        try:
            return text.decode()
        except UnicodeDecodeError as exc:
            raise CdrError(f"string is not UTF-8: {exc}") from None


def _write(w: _Writer, name: str, msg: Any) -> None:
    for fname, spec in DEFINITIONS[name]:
        base, shape, n = _parse(spec)
        value = getattr(msg, fname)
        if shape == "single":
            _write_one(w, base, value)
            continue
        items = tuple(value)
        if shape == "array" and len(items) != n:
            raise CdrError(f"{name}.{fname} must hold {n} values, got {len(items)}")
        if shape == "sequence":
            w.prim("uint32", len(items))
        for item in items:
            _write_one(w, base, item)


def _write_one(w: _Writer, base: str, value: Any) -> None:
    if base == "string":
        w.string(value)
    elif base in _PRIMITIVES:
        w.prim(base, value)
    else:
        _write(w, base, value)


def _read(r: _Reader, name: str) -> Any:
    values = {}
    for fname, spec in DEFINITIONS[name]:
        base, shape, n = _parse(spec)
        if shape == "single":
            values[fname] = _read_one(r, base)
            continue
        count = n if shape == "array" else r.prim("uint32")
        if count > len(r.data):  # each element takes at least one byte
            raise CdrError(f"{name}.{fname}: {count} elements in {len(r.data)} bytes")
        values[fname] = tuple(_read_one(r, base) for _ in range(count))
    return _CLASSES[name](**values)


def _read_one(r: _Reader, base: str) -> Any:
    if base == "string":
        return r.string()
    if base in _PRIMITIVES:
        return r.prim(base)
    return _read(r, base)


def serialize(msg: object) -> bytes:
    """The CDR bytes (with the encapsulation header) of a message of this module."""
    w = _Writer()
    try:
        _write(w, type_name_of(msg), msg)
    except struct.error as exc:
        raise CdrError(f"{type(msg).__name__}: {exc}") from None
    return _ENCAPSULATION + bytes(w.buf)


def deserialize(data: bytes, name: str) -> Any:
    """The message of type ``name`` in CDR bytes ``data`` (little endian).

    Raises
    ------
    CdrError
        Not a little-endian CDR message of that type (trailing padding allowed).
    """
    if name not in _CLASSES:
        raise ValueError(f"unknown message type {name!r}")
    data = bytes(data)
    if len(data) < 4 or data[:2] != _ENCAPSULATION[:2]:
        raise CdrError(f"not little-endian CDR (header {data[:4].hex() or 'missing'})")
    r = _Reader(data[4:])
    msg = _read(r, name)
    if len(r.data) - r.pos > 3:
        raise CdrError(f"{len(r.data) - r.pos} bytes left after a {name}")
    return msg


def _check_fields() -> None:
    """The dataclasses and :data:`DEFINITIONS` name the same fields (import-time check)."""
    for name, cls in _CLASSES.items():
        if tuple(f.name for f in fields(cls)) != tuple(f for f, _ in DEFINITIONS[name]):
            raise RuntimeError(f"fields of {cls.__name__} differ from {name}")


_check_fields()
