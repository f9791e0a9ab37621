"""A fault injector for the services' transport: lose and delay incoming messages.

For tests and benchmarks of the distributed controller under loss and delay
(a network namespace is not available everywhere; TCP under packet loss also
retransmits rather than loses). Set ``SQPMPC_FAULTS`` in the environment of
a service (the launcher passes its environment on), e.g.::

    SQPMPC_FAULTS="drop=0.2,delay=2,seed=7,kinds=plan+cmd"

- ``drop``: probability that an incoming message is lost (0..1);
- ``delay``: samples an incoming message is held back: it is delivered once
  this process has seen ``delay`` later samples of the plant's state stream
  (states received, or published by the plant), so ``delay`` means the same in
  lockstep and in real time;
- ``seed``: seed of the random draws (each process draws its own stream, from
  the seed and its name);
- ``kinds``: the message kinds affected, ``+``-separated among ``state``,
  ``cmd``, ``plan``, ``done`` (default ``plan``);
- ``mute``: from the plant's sample ``mute`` on (as this process sees the
  states), the process publishes nothing more while its liveliness token
  stays: a hung or compromised controller that is there but silent.

Liveliness tokens are never affected. The injector runs on the thread that
reads the inbox (:meth:`services.transport.Bus.get`), never in a Zenoh callback.
"""

from __future__ import annotations

import hashlib
import os
from collections import deque
from dataclasses import dataclass

import msgpack
import numpy as np

__all__ = ["ENV", "KINDS", "FaultInjector", "FaultSpec", "kind_of_key"]

ENV = "SQPMPC_FAULTS"
"""Environment variable holding the fault specification."""
KINDS = ("state", "cmd", "plan", "done")
"""Message kinds the injector can affect."""
MAX_DELAY = 1000
"""Largest ``delay`` accepted, samples."""


def kind_of_key(parts: list[str]) -> str | None:
    """The message kind of a key below the run prefix (``None``: not a message key)."""
    if len(parts) == 2 and parts[0] == "plant" and parts[1] in ("state", "done"):
        return parts[1]
    if len(parts) >= 3 and parts[0] == "robot" and parts[2] in ("cmd", "plan"):
        return parts[2]
    return None


@dataclass(frozen=True, slots=True)
class FaultSpec:
    """What to inject (see the module notes).

    Raises
    ------
    ValueError
        A field out of range (the message names it and the variable).
    """

    drop: float = 0.0
    delay: int = 0
    seed: int = 0
    kinds: tuple[str, ...] = ("plan",)
    mute: int | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.drop <= 1.0:
            raise ValueError(f"{ENV}: drop must be within [0, 1], got {self.drop!r}")
        if not 0 <= self.delay <= MAX_DELAY:
            raise ValueError(f"{ENV}: delay must be an integer in 0..{MAX_DELAY} (samples), "
                             f"got {self.delay!r}")
        if self.mute is not None and self.mute < 0:
            raise ValueError(f"{ENV}: mute must be a sample >= 0, got {self.mute!r}")
        bad = [k for k in self.kinds if k not in KINDS]
        if bad or not self.kinds:
            raise ValueError(f"{ENV}: kinds must be among {'+'.join(KINDS)}, got "
                             f"{'+'.join(self.kinds)!r}")

    @property
    def active(self) -> bool:
        """Whether anything is injected."""
        return self.drop > 0.0 or self.delay > 0 or self.mute is not None

    @classmethod
    def parse(cls, text: str) -> FaultSpec:
        """Parse ``key=value,...`` (see the module notes)."""
        fields: dict[str, object] = {}
        for item in (p.strip() for p in text.split(",")):
            if not item:
                continue
            key, sep, value = item.partition("=")
            key = key.strip()
            try:
                if not sep:
                    raise ValueError
                if key == "drop":
                    fields["drop"] = float(value)
                elif key in ("delay", "seed", "mute"):
                    fields[key] = int(value)
                elif key == "kinds":
                    fields["kinds"] = tuple(k.strip() for k in value.split("+") if k.strip())
                else:
                    raise ValueError(f"{ENV}: unknown field {key!r} (drop, delay, seed, kinds, "
                                     "mute)")
            except ValueError as exc:
                if str(exc).startswith(ENV):
                    raise
                raise ValueError(f"{ENV}: cannot read {item!r}, expected key=value with a "
                                 "number (drop, delay, seed, mute) or kinds=a+b") from None
        return cls(**fields)  # type: ignore[arg-type]


class FaultInjector:
    """Applies a :class:`FaultSpec` to the events of one bus.

    Parameters
    ----------
    spec
        What to inject.
    name
        The process's name (its random stream is drawn from the seed and this).

    Attributes
    ----------
    dropped, delayed
        Messages lost and held back so far.
    """

    def __init__(self, spec: FaultSpec, name: str) -> None:
        self.spec = spec
        digest = hashlib.sha256(f"{spec.seed}/{name}".encode()).digest()
        self.rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
        self.clock = -1  # newest state sample seen
        self.held: deque[tuple[int, object]] = deque()
        self.dropped = 0
        self.delayed = 0

    @classmethod
    def from_env(cls, name: str, environ: dict[str, str] | None = None) -> FaultInjector | None:
        """The injector configured by :data:`ENV`, or ``None`` (unset or inactive)."""
        text = (os.environ if environ is None else environ).get(ENV, "").strip()
        if not text:
            return None
        spec = FaultSpec.parse(text)
        return cls(spec, name) if spec.active else None

    def tick(self, sample: int) -> None:
        """A state of ``sample`` was seen (received or published)."""
        if sample > self.clock:
            self.clock = sample

    def muted(self) -> bool:
        """Whether this process must publish nothing more (``mute``)."""
        return self.spec.mute is not None and self.clock >= self.spec.mute

    def admit(self, kind: str | None, payload: bytes, event: object) -> list[object]:
        """Events to deliver now, given one more received ``event`` of ``kind``.

        A state advances the clock when it arrives (also when it is then lost or
        held), by at most :data:`MAX_DELAY` + 1 samples at a time once started.
        """
        if kind == "state":
            try:
                sample = msgpack.unpackb(payload, raw=False).get("sample")
            except Exception:  # garbage: the validator refuses it later
                sample = None
            if type(sample) is int and (self.clock < 0 or sample <= self.clock + MAX_DELAY + 1):
                self.tick(sample)
        if kind in self.spec.kinds:
            if self.spec.drop > 0.0 and self.rng.random() < self.spec.drop:
                self.dropped += 1
                return self.release()
            if self.spec.delay > 0:
                self.delayed += 1
                self.held.append((self.clock + self.spec.delay, event))
                return self.release()
        return [*self.release(), event] if self.held else [event]

    def release(self) -> list[object]:
        """Held events whose delay has passed."""
        out = []
        while self.held and self.held[0][0] <= self.clock:
            out.append(self.held.popleft()[1])
        return out
