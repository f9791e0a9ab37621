"""Per-publisher rate and size limits, enforced by Zenoh's own interceptors on ingress.

A certified robot may publish anything on its own keys, also a flood: as
fast as it can, or payloads of megabytes. Every service's session drops such
traffic in Zenoh's routing layer, before a Python callback, a copy or a
decode costs its process anything:

- ``low_pass_filter``: every put, delete, query or reply on the run's keys
  larger than :data:`~services.messages.MAX_PAYLOAD` (what the decoder would
  refuse anyway) is dropped; ``transport/link/rx/max_message_size`` stops the
  defragmentation of larger messages early;
- ``downsampling`` (with a rate, ``--max-rate HZ``; :mod:`services.launch`
  passes ``20 / Ts`` in real time, nothing in lockstep, whose rate is the
  machine's): on each key a robot publishes (its ``cmd``, its ``plan``, its
  plans addressed to this process), a message that comes less than
  ``1 / HZ`` s after the last one let through on that key is dropped. Zenoh
  keeps this state per link, so peer to peer it is per publisher: a flood by
  robot 2 costs robot 2's own messages, never another robot's.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from .messages import MAX_PAYLOAD

__all__ = ["MAX_MESSAGE", "interceptors"]

MAX_MESSAGE = 4 * MAX_PAYLOAD
"""Largest message Zenoh reassembles from fragments, bytes (larger ones: dropped)."""


def interceptors(prefix: str, ids: Sequence[int], me: str,
                 max_rate: float | None) -> dict[str, Any]:
    """Zenoh config entries (path -> value) limiting what process ``me`` (liveliness name,
    e.g. ``"robot/3"``) accepts, for a run with the robot ``ids`` under ``prefix``."""
    conf: dict[str, Any] = {
        "low_pass_filter": [{
            "id": "payload-size", "flows": ["ingress"],
            "messages": ["put", "delete", "query", "reply"],
            "key_exprs": [f"{prefix}/**"], "size_limit": MAX_PAYLOAD}],
        "transport/link/rx/max_message_size": MAX_MESSAGE,
    }
    if max_rate is not None:
        own = me.split("/")[1] if me.startswith("robot/") else None
        rules = []
        for rid in ids:
            keys = [f"robot/{rid}/cmd", f"robot/{rid}/plan"]
            if own is not None and own != str(rid):
                keys.append(f"robot/{rid}/plan/{own}")
            rules += [{"key_expr": f"{prefix}/{k}", "freq": float(max_rate)} for k in keys]
        conf["downsampling"] = [{"id": "per-publisher-rate", "flows": ["ingress"],
                                 "messages": ["put", "delete"], "rules": rules}]
    return conf
