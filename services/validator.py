"""Decoding and validating the messages of one run (:class:`MessageValidator`).

The wire format itself (encoding, decoding, schema version) is :mod:`services.messages`.
"""

from __future__ import annotations

from collections.abc import Iterable

from .messages import (
    CmdMsg,
    DoneMsg,
    InvalidMessage,
    Message,
    Mismatch,
    PlanMsg,
    StateMsg,
    decode,
)

__all__ = ["MessageValidator"]



class MessageValidator:
    """Decode and validate messages of one run; counts what it refuses.

    On top of :func:`decode` it checks that the message type matches the key
    it arrived on, that robot ids are known (a ``state`` must list exactly the
    scenario's ids, in order; a ``cmd`` or ``plan`` must carry the id of the
    robot key it arrived on) and that a ``state`` carries the scenario digest
    this process computed. It keeps no state about sample indices: whether a
    well-formed message is timely is decided by
    :class:`services.protocol.AcceptancePolicy`.

    Parameters
    ----------
    ids
        The scenario's robot ids, in scenario order.
    horizon
        ``N`` of the scenario.
    scenario_digest
        When given, ``state`` messages must carry this digest; another non-empty
        digest raises :class:`Mismatch`.
    settings_digest
        When given, a ``state`` or ``cmd`` carrying another non-empty settings
        digest raises :class:`Mismatch`.

    Attributes
    ----------
    invalid
        Number of messages refused so far.
    stale
        Number of well-formed messages dropped as older than the receiver's loop.
    """

    _TYPES = {"state": StateMsg, "cmd": CmdMsg, "plan": PlanMsg, "done": DoneMsg}

    def __init__(self, ids: Iterable[int], horizon: int, scenario_digest: str | None = None,
                 settings_digest: str | None = None):
        self.order = tuple(int(i) for i in ids)
        self.ids = frozenset(self.order)
        self.horizon = int(horizon)
        self.scenario_digest = scenario_digest
        self.settings_digest = settings_digest
        self.invalid = 0
        self.stale = 0
        self.last_error = ""

    def _check(self, msg: Message, kind: str | None, key_id: int | None) -> None:
        if kind is not None and not isinstance(msg, self._TYPES.get(kind, ())):
            raise InvalidMessage(f"a {type(msg).__name__} on a {kind!r} key")
        if isinstance(msg, DoneMsg):
            return
        if isinstance(msg, StateMsg):
            # another scenario (a plant started with another one) first: its robots may differ
            if self.scenario_digest is not None and msg.scenario != self.scenario_digest:
                text = (f"scenario digest {msg.scenario!r} differs from "
                        f"{self.scenario_digest!r}: same --scenario and overrides?")
                raise Mismatch(text, msg) if msg.scenario else InvalidMessage(text)
            if msg.ids != self.order:
                raise InvalidMessage(f"state for robots {list(msg.ids)}, expected "
                                     f"{list(self.order)}")
            self._check_settings(msg)
            for rid, ages in (msg.plan_ages or {}).items():
                self._check_ages(rid, ages)
            return
        if msg.id not in self.ids:
            raise InvalidMessage(f"unknown robot id {msg.id}")
        if key_id is not None and key_id != msg.id:
            raise InvalidMessage(f"id {msg.id} on the key of robot {key_id}")
        if isinstance(msg, CmdMsg):
            self._check_settings(msg)
            if msg.plan_ages:
                self._check_ages(msg.id, msg.plan_ages)

    def _check_settings(self, msg: StateMsg | CmdMsg) -> None:
        if self.settings_digest and msg.settings and msg.settings != self.settings_digest:
            raise Mismatch(f"settings digest {msg.settings!r} differs from "
                           f"{self.settings_digest!r}", msg)

    def _check_ages(self, rid: int, ages: dict[int, int]) -> None:
        """Plan ages of robot ``rid``: known robots, neighbours of ``rid`` (not itself)."""
        if rid not in self.ids:
            raise InvalidMessage(f"'plan_ages' of unknown robot id {rid}")
        for j in ages:
            if j not in self.ids or j == rid:
                raise InvalidMessage(f"'plan_ages' of robot {rid} names robot {j}, not one of "
                                     "its neighbours")

    def check(self, payload: bytes, kind: str | None = None,
              key_id: int | None = None) -> Message:
        """Validate a payload received on a key of ``kind`` (for robot ``key_id``).

        Raises
        ------
        InvalidMessage
            The message must be dropped (the counter is already incremented).
        """
        try:
            msg = decode(payload, self.horizon)
            self._check(msg, kind, key_id)
            return msg
        except InvalidMessage as exc:
            self.invalid += 1
            self.last_error = str(exc)
            raise

    def refuse(self, reason: str) -> None:
        """Count a message refused for a reason found by the caller (e.g. unknown key)."""
        self.invalid += 1
        self.last_error = reason
