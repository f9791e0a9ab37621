"""What each process of a run accepts of each message kind: the one acceptance policy.

:mod:`services.messages` checks that a payload is well formed and belongs to
this run (schema, ids, key, scenario digest). Whether a well-formed message
is *timely* -- its sample index against where the receiving loop is -- is
decided here and nowhere else, so that no message (forged, duplicated,
replayed, delayed, from the future) can stop a loop or move it backwards.

=========  ==========  ======================================================================
kind       receiver    rule (``K`` samples, ``Ts``, ``N``; ``c`` the receiver's cursor)
=========  ==========  ======================================================================
``state``  controller  ``0 <= k < K`` and ``t = k Ts`` (else refused, counted invalid);
                       ``k = c + 1``: accepted; ``k > c + 1``: accepted as a *provisional*
                       forward jump (states were lost, or a controller fell behind);
                       ``k = c``: a repeat (the plant asks again: the controller re-sends
                       what it published for ``k``); ``k < c``: stale, dropped, unless ``c``
                       was reached by a provisional jump and ``k`` lies after the sample
                       before it: then ``k`` is accepted and the jump forgotten (the plant
                       publishes in order, so a later real state below a jump proves the
                       jump was not the plant's: a forged future state costs one step, it
                       cannot lock the stream)
``cmd``    plant       ``k = `` the plant's current sample: accepted (a repeat replaces the
                       input with an identical one); ``k <`` current: stale (counted as a
                       late command); ``k >`` current: refused
``plan``   robot       ``c - N - 1 <= k <= c + N + 2`` and ``k < K``: accepted once per
                       sender and sample (a second copy is a repeat, dropped: the first
                       wins); older: stale; newer or ``k >= K``: refused
``done``   controller  ``c' <= k <= K`` with ``c'`` the newest sample not reached by a
                       provisional jump, and ``completed`` only with ``k = K``; else refused
=========  ==========  ======================================================================

Repeats are not errors (the plant re-publishes a sample's states while inputs
are missing, :mod:`services.plant`); stale messages are counted apart from
invalid ones. ``tests/test_protocol.py`` checks every row.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

__all__ = ["AcceptancePolicy", "Decision", "StateCursor", "Verdict"]


class Verdict(enum.Enum):
    """What to do with a well-formed message."""

    ACCEPT = "accept"
    """Use it."""
    REPEAT = "repeat"
    """A copy of what was accepted already: not an error (answer or ignore it)."""
    STALE = "stale"
    """Older than what the receiver is at: drop it, count it apart from invalid ones."""
    REFUSE = "refuse"
    """Impossible in this run (beyond its end, inconsistent, far ahead): drop it, count it
    invalid."""


@dataclass(frozen=True, slots=True)
class Decision:
    """A verdict with its reason (empty when accepted)."""

    verdict: Verdict
    reason: str = ""

    @property
    def accepted(self) -> bool:
        """Whether the verdict is :attr:`Verdict.ACCEPT`."""
        return self.verdict is Verdict.ACCEPT


_ACCEPT = Decision(Verdict.ACCEPT)


@dataclass(slots=True)
class StateCursor:
    """Where a controller is in the plant's state stream.

    Attributes
    ----------
    sample
        Newest state sample accepted (-1: none yet).
    floor
        When :attr:`sample` was reached by a forward jump not confirmed since: the
        sample accepted before the jump; ``None`` otherwise.
    """

    sample: int = -1
    floor: int | None = None

    @property
    def confirmed(self) -> int:
        """The newest sample not reached by a provisional jump."""
        return self.sample if self.floor is None else self.floor


@dataclass(frozen=True, slots=True)
class AcceptancePolicy:
    """The acceptance rules of one run (see the module's table).

    Parameters
    ----------
    steps
        ``K``: samples of the run (states ``0..K-1`` are published).
    sample_time
        ``Ts``, s.
    horizon
        ``N``.
    """

    steps: int
    sample_time: float
    horizon: int

    def state(self, cursor: StateCursor, sample: int, t: float) -> Decision:
        """A state of ``sample`` at time ``t`` received by a controller at ``cursor``."""
        if not 0 <= sample < self.steps:
            return Decision(Verdict.REFUSE, f"state of sample {sample} outside the run "
                                            f"(0..{self.steps - 1})")
        expected = sample * self.sample_time
        if abs(t - expected) > 1e-9 * max(1.0, abs(expected)):
            return Decision(Verdict.REFUSE, f"state of sample {sample} at t = {t!r}, expected "
                                            f"{expected!r}")
        if sample == cursor.sample:
            return Decision(Verdict.REPEAT, f"state of sample {sample} again")
        if sample > cursor.sample:
            return _ACCEPT
        if cursor.floor is not None and sample > cursor.floor:
            return _ACCEPT  # below a provisional jump: the jump was not the plant's
        return Decision(Verdict.STALE, f"state of sample {sample}, already at {cursor.sample}")

    @staticmethod
    def advance(cursor: StateCursor, sample: int) -> None:
        """Move ``cursor`` to an accepted state of ``sample`` (see :meth:`state`)."""
        if sample == cursor.sample + 1 or sample < cursor.sample:
            cursor.floor = None  # in order, or a resync below a provisional jump
        elif cursor.floor is None:
            cursor.floor = cursor.sample  # a forward jump: provisional
        cursor.sample = sample

    def cmd(self, current: int, sample: int) -> Decision:
        """An input for ``sample`` received by the plant at sample ``current``."""
        if sample == current:
            return _ACCEPT
        if sample < current:
            return Decision(Verdict.STALE, f"input for sample {sample} after the plant moved "
                                           f"on to {current}")
        return Decision(Verdict.REFUSE, f"input for sample {sample} ahead of the plant's "
                                        f"{current}")

    def plan(self, cursor: int, sample: int, held: bool) -> Decision:
        """A neighbour's plan of ``sample`` received by a robot whose cursor is ``cursor``;
        ``held``: a plan of that sender and sample is already kept."""
        if sample >= self.steps or sample > cursor + self.horizon + 2:
            return Decision(Verdict.REFUSE, f"plan of sample {sample} ahead of the run "
                                            f"(at sample {cursor} of {self.steps})")
        if sample < cursor - self.horizon - 1:
            return Decision(Verdict.STALE, f"plan of sample {sample}, too old at {cursor}")
        if held:
            return Decision(Verdict.REPEAT, f"plan of sample {sample} again")
        return _ACCEPT

    def done(self, cursor: StateCursor, sample: int, completed: bool) -> Decision:
        """The plant's end after ``sample`` samples, received by a controller at ``cursor``."""
        if not cursor.confirmed <= sample <= self.steps:
            return Decision(Verdict.REFUSE, f"done after {sample} samples, at "
                                            f"{cursor.confirmed} of {self.steps}")
        if completed and sample != self.steps:
            return Decision(Verdict.REFUSE, f"completed after {sample} of {self.steps} samples")
        return _ACCEPT
