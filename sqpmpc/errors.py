"""Exception hierarchy of sqpmpc.

Every error the library raises on purpose derives from :class:`SqpmpcError`:

- :class:`ScenarioError`: a scenario file or built-in name that cannot be used
  (unreadable, unknown key, wrong type or shape, inconsistent values). The
  message names the file, the key and what was expected.
- :class:`ProblemError`: data handed to the library that does not fit the
  problem it was built for (wrong shapes, non-finite values, unknown robot ids).
- :class:`SolverError`: the QP solver could not be set up or returned something
  unusable where the caller asked to raise instead of falling back.
- :class:`DependencyError`: an optional part needs an extra that is not
  installed (the message names the extra).
"""

from __future__ import annotations

__all__ = ["DependencyError", "ProblemError", "ScenarioError", "SolverError", "SqpmpcError"]


class SqpmpcError(Exception):
    """Base class of every error raised by sqpmpc on purpose."""


class ScenarioError(SqpmpcError):
    """A scenario file or name is invalid.

    Parameters
    ----------
    source
        File path or built-in name the scenario came from.
    key
        Dotted key path of the offending entry, e.g. ``robots[2].diameter``;
        empty when the problem concerns the whole file.
    message
        What was wrong and what was expected.
    """

    def __init__(self, source: str, key: str, message: str) -> None:
        self.source = source
        self.key = key
        self.detail = message
        where = f"{source}: {key}: " if key else f"{source}: "
        super().__init__(where + message)


class ProblemError(SqpmpcError):
    """Input data do not match the problem dimensions or are not finite."""


class SolverError(SqpmpcError):
    """The QP solver failed in a way the caller asked to be raised."""


class DependencyError(SqpmpcError):
    """An optional part of sqpmpc needs an extra that is not installed."""
