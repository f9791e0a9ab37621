"""Scheduling priority of a real-time service process (``--priority``).

A robot's controller is a real-time task: on a real robot it runs with a
real-time scheduling priority, so that nothing else on its computer (a
logger, a busy update, a process an attacker started) can take the CPU from
it when its sample comes. ``--priority`` does the same for the services:

- ``off`` (the opt-out): the process keeps the priority it was started with;
- ``auto`` (the default, of a service started by hand too, and what
  :mod:`services.launch` passes in real time; a lockstep run's sample loops never
  raise theirs): ``SCHED_RR`` at
  :data:`RT_PRIORITY` where the process may (root or ``CAP_SYS_NICE``, or an
  ``RLIMIT_RTPRIO`` allowing it), else a nice value of :data:`NICE` where it
  may, else nothing; the outcome is logged once;
- ``N`` (1-99): ``SCHED_RR`` at priority ``N``, or one error line (status 2)
  where the process may not.

The change applies to every thread of the process (Zenoh's receive and
transmit threads included: a state or an input it cannot read in time is as
late as one never computed) and to the threads they start later. It is made
when the sample loop starts (:func:`raise_priority`), not at start-up: the
imports, the kernel compilation and the first sample (whose deadline is not
timed) run at the normal priority, so a start-up never holds a core at a
real-time priority. Every service blocks between samples (it waits on its
inbox), so a real-time process takes only the CPU its samples need; Linux's
real-time throttling (``kernel.sched_rt_runtime_us``, 95 % by default) keeps
a share for every other process whatever happens.
"""

from __future__ import annotations

import argparse
import logging
import os
from dataclasses import dataclass

__all__ = ["NICE", "RT_PRIORITY", "Priority", "check_priority", "parse_priority",
           "raise_priority"]

log = logging.getLogger(__name__)

RT_PRIORITY = 20
"""``SCHED_RR`` priority of ``--priority auto`` (1-99; 50 is the kernel's IRQ threads')."""
NICE = -10
"""Nice value of ``--priority auto`` where ``SCHED_RR`` is not permitted."""


@dataclass(frozen=True)
class Priority:
    """A ``--priority`` setting: ``mode`` ``"off"``, ``"auto"`` or ``"rr"`` (``level``)."""

    mode: str
    level: int = RT_PRIORITY

    def __post_init__(self) -> None:
        if self.mode not in ("off", "auto", "rr"):
            raise ValueError(f"priority mode must be off, auto or rr, got {self.mode!r}")
        if not 1 <= self.level <= 99:
            raise ValueError(f"a SCHED_RR priority is 1-99, got {self.level}")


def parse_priority(text: str) -> Priority:
    """``--priority`` value: ``off``, ``auto`` or a ``SCHED_RR`` priority 1-99."""
    if text in ("off", "auto"):
        return Priority(text)
    try:
        level = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected off, auto or a real-time priority 1-99, got {text!r}") from None
    if not 1 <= level <= 99:
        raise argparse.ArgumentTypeError(f"a real-time priority is 1-99, got {level}")
    return Priority("rr", level)


def _threads() -> list[int]:
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:  # not Linux: the calling thread only
        return [0]


def raise_priority(priority: Priority, name: str) -> str:
    """Apply ``priority`` to every thread of this process; returns what was done (one
    phrase, also logged). Raises :class:`PermissionError` for an explicit ``N`` the
    process may not take."""
    if priority.mode == "off" or not hasattr(os, "sched_setscheduler"):
        return "normal priority"
    try:
        param = os.sched_param(priority.level)
        for tid in _threads():
            try:
                os.sched_setscheduler(tid, os.SCHED_RR, param)
            except ProcessLookupError:  # a thread that ended meanwhile
                pass
        done = f"SCHED_RR priority {priority.level}"
    except PermissionError:
        if priority.mode == "rr":
            raise PermissionError(
                f"--priority {priority.level}: SCHED_RR is not permitted (needs root, "
                "CAP_SYS_NICE or an RLIMIT_RTPRIO allowing it)") from None
        try:
            for tid in _threads():
                try:
                    os.setpriority(os.PRIO_PROCESS, tid, NICE)
                except ProcessLookupError:
                    pass
            done = f"nice {NICE} (SCHED_RR not permitted)"
        except PermissionError:
            done = "normal priority (neither SCHED_RR nor a negative nice is permitted)"
    log.info("%s: sample loop at %s", name, done)
    return done


def check_priority(priority: Priority) -> None:
    """At start-up: raise :class:`PermissionError` (one line) when an explicit ``N`` will
    not be permitted (the calling thread takes it and gives it back at once)."""
    if priority.mode != "rr" or not hasattr(os, "sched_setscheduler"):
        return
    before, param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(priority.level))
    except PermissionError:
        raise PermissionError(
            f"--priority {priority.level}: SCHED_RR is not permitted (needs root, "
            "CAP_SYS_NICE or an RLIMIT_RTPRIO allowing it)") from None
    os.sched_setscheduler(0, before, param)
