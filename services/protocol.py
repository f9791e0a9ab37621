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
                       ``k > c``: accepted (``k > c + 1``: states were lost, or a controller
                       fell behind and skips ahead); ``k = c``: a repeat (the plant asks
                       again: the controller re-sends what it published for ``k``);
                       ``k < c``: stale, dropped -- unless the same ``k`` comes a second time
                       while the cursor is still ahead: the plant re-publishes the sample it
                       waits for, so a sample asked for again is the plant's, and the cursor
                       goes back to it (the cursor was ahead of the plant only if a state
                       was forged: a forged future state costs a step, it cannot lock the
                       stream; a replayed old one, likewise)
``cmd``    plant       ``k = `` the plant's current sample: accepted (a repeat replaces the
                       input with an identical one); ``k <`` current: stale (counted as a
                       late command); ``k >`` current: refused
``plan``   robot       ``c - N - 1 <= k <= c + N + 2`` and ``k < K``: accepted once per
                       sender and sample (a second copy is a repeat, dropped: the first
                       wins); older: stale; newer or ``k >= K``: refused
``done``   controller  ``c <= k <= K`` and ``completed`` only with ``k = K``; else refused
=========  ==========  ======================================================================

The ``plan_ages`` a ``cmd`` carries (checked by :class:`~services.validator.MessageValidator`:
neighbours of the sender, ages ``1..N+2``) are relayed by the plant with the states of
``k + 1`` only for the inputs it applied at ``k`` (accepted by the ``cmd`` row): a stale,
refused or forged-ahead input relays nothing, and every robot reads the same relay in the
same state message.

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
    asked
        An older sample received once while the cursor was ahead (``None``: none):
        received again, it is the plant's and the cursor goes back to it.
    """

    sample: int = -1
    asked: int | None = None


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
        if sample > cursor.sample or sample == cursor.asked:
            return _ACCEPT  # ahead, or asked for again: the plant is there
        cursor.asked = sample
        return Decision(Verdict.STALE, f"state of sample {sample}, already at {cursor.sample}")

    @staticmethod
    def advance(cursor: StateCursor, sample: int) -> None:
        """Move ``cursor`` to an accepted state of ``sample`` (see :meth:`state`)."""
        cursor.sample = sample
        cursor.asked = None

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
        if not cursor.sample <= sample <= self.steps:
            return Decision(Verdict.REFUSE, f"done after {sample} samples, at "
                                            f"{cursor.sample} of {self.steps}")
        if completed and sample != self.steps:
            return Decision(Verdict.REFUSE, f"completed after {sample} of {self.steps} samples")
        return _ACCEPT
