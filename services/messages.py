"""Wire schema of the sqpmpc services: msgpack maps, version 1.

Every payload is a msgpack map with string keys, carrying ``"v"`` (schema
version, :data:`SCHEMA_VERSION`) and ``"type"``. Arrays are msgpack ``bin``
values holding little-endian float64 numbers in row-major order (their shape
is fixed by the schema and the scenario's horizon ``N``), so values
round-trip exactly and decode in one copy. Unknown extra keys are ignored (a
later minor addition does not break an older reader); anything else that does
not match is refused by :class:`services.validator.MessageValidator` with
:class:`InvalidMessage`, which the services count and drop.

=========  ==========================================================================
type       fields (besides ``v`` and ``type``)
=========  ==========================================================================
``state``  ``sample`` int >= 0, ``t`` float (time t_k, s), ``ids`` [int] (every robot,
           scenario order), ``x`` n x 3 (x, y, psi of each robot), ``budget`` float > 0
           or nil (wall-clock seconds the controllers have in real-time mode; nil in
           lockstep), ``scenario`` str (digest of the scenario and its overrides);
           optional ``settings`` str (digest of the settings the run's processes agree
           on, :mod:`services.agreement`; absent or empty: not checked);
           optional ``plan_ages`` [[robot id, [[neighbour id, age], ...]], ...] (the
           ``plan_ages`` of the inputs the plant applied at ``k - 1``, relayed: both robots
           of a pair agree on the plans of their shared row from it; empty when absent)
``cmd``    ``id`` int, ``sample`` int >= 0, ``u`` [v, omega], ``compute_time`` float >= 0 (s),
           ``fallback`` str or nil, ``invalid`` int >= 0 (messages the sender dropped);
           optional ``counters`` {str: int >= 0} (the sending controller's totals so far:
           engine and rule counters, ``sqpmpc rules``; at most 64 entries; empty when
           absent); optional ``settings`` str (the sender's settings digest) and
           ``detail`` {str: str} (its settings, at most 32 entries: a controller that
           refuses the plant's settings sends them once, with a braking ``u``);
           optional ``plan_ages`` [[neighbour id, age], ...] (neighbours whose
           newest plan the sender held at its step ``k`` was ``age >= 2`` samples old,
           ``age <= N + 2``; empty when absent)
``plan``   ``id`` int, ``sample`` int >= 0, ``t`` float (time t_k), ``stamp`` float (sender's wall
           clock, Unix s), ``states`` (N+1) x 3, ``inputs`` N x 2
``done``   ``sample`` int (samples simulated), ``completed`` bool
=========  ==========================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np

__all__ = [
    "MAX_PAYLOAD",
    "MAX_PLAN_AGES",
    "SCHEMA_VERSION",
    "CmdMsg",
    "DoneMsg",
    "InvalidMessage",
    "Mismatch",
    "Message",
    "PlanMsg",
    "StateMsg",
    "decode",
    "encode",
    "peek_plan",
]

SCHEMA_VERSION = 1
"""Version carried in every message (``"v"``); also the ``@v1`` chunk of the key space."""
MAX_PAYLOAD = 1 << 16
"""Payloads larger than this (bytes) are refused before unpacking."""
MAX_PLAN_AGES = 4096
"""Most ``[neighbour, age]`` entries in one cmd, and in all of one state's ``plan_ages``."""


class InvalidMessage(ValueError):
    """A payload that does not match the schema; it is dropped and counted."""


class Mismatch(InvalidMessage):
    """A well-formed message from a process of the run started with another scenario or
    other settings (``msg``: the message)."""

    def __init__(self, text: str, msg: Message) -> None:
        super().__init__(text)
        self.msg = msg


@dataclass(frozen=True, slots=True)
class StateMsg:
    """The states of every robot at sample ``k`` (published by the plant)."""

    sample: int
    t: float
    ids: tuple[int, ...]
    x: np.ndarray
    budget: float | None = None
    scenario: str = ""
    settings: str = ""
    plan_ages: dict[int, dict[int, int]] | None = None
    """Per robot whose input of ``k - 1`` the plant applied, its ``plan_ages`` (relayed)."""
    gone: tuple[int, ...] = ()
    """Robots whose controllers left the run for good (not back within the plant's
    ``--rejoin-timeout``): every controller is told the same at the same sample."""
    v: np.ndarray | None = None
    """The robots' measured velocities ``(v, omega)`` ``(n, 2)`` where the plant has them
    (acceleration bounds: :meth:`sqpmpc.problem.plant.Plant.measure`), else ``None``."""


@dataclass(frozen=True, slots=True)
class CmdMsg:
    """A controller's input for one robot at sample ``k`` (read by the plant)."""

    id: int
    sample: int
    u: np.ndarray
    compute_time: float
    fallback: str | None = None
    invalid: int = 0
    counters: dict[str, int] | None = None
    settings: str = ""
    detail: dict[str, str] | None = None
    plan_ages: dict[int, int] | None = None
    """Per neighbour, the age (``>= 2`` samples) of the newest plan held at this step;
    neighbours not listed: a plan of ``k - 1`` (or none yet)."""


@dataclass(frozen=True, slots=True)
class PlanMsg:
    """A robot's predicted horizon computed at sample ``k`` (read by its neighbours)."""

    id: int
    sample: int
    t: float
    stamp: float
    states: np.ndarray
    inputs: np.ndarray


@dataclass(frozen=True, slots=True)
class DoneMsg:
    """The plant finished (or stopped): controllers may exit."""

    sample: int
    completed: bool


Message = StateMsg | CmdMsg | PlanMsg | DoneMsg


_F64 = np.dtype("<f8")


def _floats(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype=_F64).tobytes()


def encode(msg: Message) -> bytes:
    """Serialize a message to msgpack bytes.

    Parameters
    ----------
    msg
        One of :class:`StateMsg`, :class:`CmdMsg`, :class:`PlanMsg`, :class:`DoneMsg`.

    Returns
    -------
    bytes
        The payload.
    """
    if isinstance(msg, StateMsg):
        body = {"type": "state", "sample": int(msg.sample), "t": float(msg.t),
                "ids": [int(i) for i in msg.ids], "x": _floats(msg.x),
                "budget": None if msg.budget is None else float(msg.budget),
                "scenario": msg.scenario}
        if msg.settings:
            body["settings"] = msg.settings
        if msg.plan_ages:
            body["plan_ages"] = [[int(r), _pairs(a)] for r, a in msg.plan_ages.items() if a]
        if msg.gone:
            body["gone"] = [int(i) for i in msg.gone]
        if msg.v is not None:
            body["velocities"] = _floats(msg.v)
    elif isinstance(msg, CmdMsg):
        body = {"type": "cmd", "id": int(msg.id), "sample": int(msg.sample), "u": _floats(msg.u),
                "compute_time": float(msg.compute_time), "fallback": msg.fallback,
                "invalid": int(msg.invalid),
                "counters": {str(k): int(v) for k, v in (msg.counters or {}).items()}}
        if msg.settings:
            body["settings"] = msg.settings
        if msg.detail is not None:
            body["detail"] = {str(k): str(v) for k, v in msg.detail.items()}
        if msg.plan_ages:
            body["plan_ages"] = _pairs(msg.plan_ages)
    elif isinstance(msg, PlanMsg):
        body = {"type": "plan", "id": int(msg.id), "sample": int(msg.sample), "t": float(msg.t),
                "stamp": float(msg.stamp), "states": _floats(msg.states),
                "inputs": _floats(msg.inputs)}
    elif isinstance(msg, DoneMsg):
        body = {"type": "done", "sample": int(msg.sample), "completed": bool(msg.completed)}
    else:
        raise TypeError(f"not a message: {type(msg).__name__}")
    return msgpack.packb({"v": SCHEMA_VERSION, **body}, use_bin_type=True)


def _pairs(ages: dict[int, int]) -> list[list[int]]:
    return [[int(j), int(a)] for j, a in ages.items()]


_PLAN_HEAD = b"\x88\xa1v\x01\xa4type\xa4plan\xa2id"
"""How :func:`encode` starts every plan: the map of 8 entries, ``v``, ``type``, ``id``."""
_SAMPLE_KEY = b"\xa6sample"
_UINT_WIDTH = {0xCC: 1, 0xCD: 2, 0xCE: 4, 0xCF: 8}


def _peek_uint(buf: bytes, pos: int) -> tuple[int, int] | None:
    """A msgpack unsigned integer at ``pos``: its value and the next position."""
    if pos >= len(buf):
        return None
    head = buf[pos]
    if head < 0x80:
        return head, pos + 1
    width = _UINT_WIDTH.get(head)
    if width is None or pos + 1 + width > len(buf):
        return None
    return int.from_bytes(buf[pos + 1:pos + 1 + width], "big"), pos + 1 + width


def peek_plan(payload: bytes) -> tuple[int, int] | None:
    """``(id, sample)`` of a plan laid out as :func:`encode` writes it, without decoding it.

    Reads a few header bytes only (about a microsecond; a full :func:`decode`
    with its checks costs ten times more). Returns ``None`` for anything laid
    out otherwise (another encoder, another type, a negative id, garbage): the
    caller then decodes it in full. A header that parses says nothing about
    the rest of the payload: the body is checked when it is decoded.
    """
    if not isinstance(payload, bytes) or not payload.startswith(_PLAN_HEAD):
        return None
    rid = _peek_uint(payload, len(_PLAN_HEAD))
    if rid is None or payload[rid[1]:rid[1] + len(_SAMPLE_KEY)] != _SAMPLE_KEY:
        return None
    sample = _peek_uint(payload, rid[1] + len(_SAMPLE_KEY))
    return None if sample is None else (rid[0], sample[0])


# ----------------------------------------------------------------------------- field checks
def _int(body: dict[str, Any], key: str, minimum: int | None = None) -> int:
    value = body.get(key)
    if type(value) is not int:
        raise InvalidMessage(f"{key!r} must be an integer, got {type(value).__name__}")
    if minimum is not None and value < minimum:
        raise InvalidMessage(f"{key!r} must be >= {minimum}, got {value}")
    return value


def _float(body: dict[str, Any], key: str, optional: bool = False) -> float | None:
    value = body.get(key)
    if value is None and optional:
        return None
    if type(value) not in (float, int):
        raise InvalidMessage(f"{key!r} must be a number, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise InvalidMessage(f"{key!r} must be finite, got {value}")
    return value


def _array(body: dict[str, Any], key: str, shape: tuple[int, ...]) -> np.ndarray:
    value = body.get(key)
    size = 8 * math.prod(shape)
    if not isinstance(value, bytes):
        raise InvalidMessage(f"{key!r} must be bin (float64 bytes), got {type(value).__name__}")
    if len(value) != size:
        raise InvalidMessage(f"{key!r} must hold {shape} float64 ({size} bytes), "
                             f"got {len(value)} bytes")
    a = np.frombuffer(value, dtype=_F64).astype(np.float64).reshape(shape)
    if not np.isfinite(a).all():
        raise InvalidMessage(f"{key!r} must be finite")
    return a


def decode(payload: bytes, horizon: int) -> Message:
    """Parse and type-check a payload (no cross-message checks).

    Parameters
    ----------
    payload
        Raw bytes received.
    horizon
        ``N``: fixes the shapes of a plan's arrays.

    Raises
    ------
    InvalidMessage
        Anything that is not a well-formed version-1 message.
    """
    if not isinstance(payload, bytes | bytearray | memoryview):
        raise InvalidMessage(f"payload must be bytes, got {type(payload).__name__}")
    if len(payload) > MAX_PAYLOAD:
        raise InvalidMessage(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    try:
        body = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise InvalidMessage(f"not msgpack: {type(exc).__name__}: {exc}") from None
    if not isinstance(body, dict):
        raise InvalidMessage(f"payload must be a map, got {type(body).__name__}")
    version = body.get("v")
    if type(version) is not int or version != SCHEMA_VERSION:
        raise InvalidMessage(f"unsupported schema version {version!r} "
                             f"(this reader speaks {SCHEMA_VERSION})")
    kind = body.get("type")
    if kind == "state":
        scenario = body.get("scenario", "")
        if not isinstance(scenario, str):
            raise InvalidMessage("'scenario' must be a string")
        budget = _float(body, "budget", optional=True)
        if budget is not None and budget <= 0.0:
            raise InvalidMessage(f"'budget' must be positive, got {budget}")
        ids = body.get("ids")
        if (not isinstance(ids, list) or not ids or len(ids) > 4096
                or any(type(i) is not int for i in ids)):
            raise InvalidMessage("'ids' must be a non-empty list of integers")
        gone = body.get("gone", [])
        if (not isinstance(gone, list) or len(gone) > len(ids)
                or any(type(i) is not int or i not in ids for i in gone)):
            raise InvalidMessage("'gone' must be a list of the message's robot ids")
        return StateMsg(_int(body, "sample", 0), _float(body, "t"), tuple(ids),
                        _array(body, "x", (len(ids), 3)), budget, scenario,
                        _text(body, "settings"),
                        _relayed_ages(body, horizon) or None, tuple(sorted(set(gone))),
                        _array(body, "velocities", (len(ids), 2)) if "velocities" in body
                        else None)
    if kind == "cmd":
        fallback = body.get("fallback")
        if fallback is not None and not isinstance(fallback, str):
            raise InvalidMessage("'fallback' must be a string or nil")
        compute_time = _float(body, "compute_time")
        if compute_time < 0.0:
            raise InvalidMessage(f"'compute_time' must be >= 0, got {compute_time}")
        return CmdMsg(_int(body, "id"), _int(body, "sample", 0), _array(body, "u", (2,)),
                      compute_time, fallback, _int(body, "invalid", 0), _counters(body),
                      _text(body, "settings"), _detail(body),
                      _ages(body.get("plan_ages", []), horizon, MAX_PLAN_AGES) or None)
    if kind == "plan":
        return PlanMsg(_int(body, "id"), _int(body, "sample", 0), _float(body, "t"),
                       _float(body, "stamp"), _array(body, "states", (horizon + 1, 3)),
                       _array(body, "inputs", (horizon, 2)))
    if kind == "done":
        completed = body.get("completed")
        if not isinstance(completed, bool):
            raise InvalidMessage("'completed' must be a boolean")
        return DoneMsg(_int(body, "sample", 0), completed)
    raise InvalidMessage(f"unknown message type {kind!r}")


def _text(body: dict[str, Any], key: str) -> str:
    """An optional short string field (empty when absent)."""
    value = body.get(key, "")
    if not isinstance(value, str) or len(value) > 64:
        raise InvalidMessage(f"{key!r} must be a string of at most 64 characters")
    return value


def _detail(body: dict[str, Any]) -> dict[str, str] | None:
    """The optional ``detail`` map of a cmd: at most 32 str keys, str values."""
    detail = body.get("detail")
    if detail is None:
        return None
    if not isinstance(detail, dict) or len(detail) > 32 or not all(
            isinstance(k, str) and len(k) <= 64 and isinstance(v, str) and len(v) <= 4096
            for k, v in detail.items()):
        raise InvalidMessage("'detail' must be a map of at most 32 strings")
    return detail


def _counters(body: dict[str, Any]) -> dict[str, int]:
    """The optional ``counters`` map of a cmd: at most 64 str keys, int values >= 0."""
    counters = body.get("counters", {})
    if not isinstance(counters, dict) or len(counters) > 64:
        raise InvalidMessage("'counters' must be a map of at most 64 entries")
    out: dict[str, int] = {}
    for key, value in counters.items():
        if not isinstance(key, str) or len(key) > 64 or type(value) is not int or value < 0:
            raise InvalidMessage("'counters' must map names to integers >= 0")
        out[key] = value
    return out


def _ages(value: Any, horizon: int, limit: int) -> dict[int, int]:
    """A ``[[neighbour id, age], ...]`` list: distinct integer ids, ages in 1..N+2."""
    if not isinstance(value, list) or len(value) > limit:
        raise InvalidMessage(f"'plan_ages' must be a list of at most {limit} [id, age] pairs")
    out: dict[int, int] = {}
    for item in value:
        if (not isinstance(item, list) or len(item) != 2 or type(item[0]) is not int
                or type(item[1]) is not int):
            raise InvalidMessage("'plan_ages' entries must be [id, age] integer pairs")
        rid, age = item
        if not 1 <= age <= horizon + 2:
            raise InvalidMessage(f"'plan_ages' ages must be within 1..{horizon + 2}, got {age}")
        if rid in out:
            raise InvalidMessage(f"'plan_ages' lists robot {rid} twice")
        out[rid] = age
    return out


def _relayed_ages(body: dict[str, Any], horizon: int) -> dict[int, dict[int, int]]:
    """A state's ``plan_ages``: ``[[robot id, [[neighbour id, age], ...]], ...]``."""
    value = body.get("plan_ages", [])
    if not isinstance(value, list) or len(value) > MAX_PLAN_AGES:
        raise InvalidMessage("'plan_ages' must be a list of [robot id, [[id, age], ...]]")
    out: dict[int, dict[int, int]] = {}
    total = 0
    for item in value:
        if not isinstance(item, list) or len(item) != 2 or type(item[0]) is not int:
            raise InvalidMessage("'plan_ages' entries must be [robot id, [[id, age], ...]]")
        if item[0] in out:
            raise InvalidMessage(f"'plan_ages' lists robot {item[0]} twice")
        ages = _ages(item[1], horizon, MAX_PLAN_AGES - total)
        total += len(ages)
        out[item[0]] = ages
    return out


