r"""The rule interface: liveness heuristics as named plug-ins of the per-sample pipeline.

A *rule* is a frozen, validated dataclass holding its own parameters. A rule
is on when it is in :attr:`sqpmpc.control.settings.SolverSettings.rules` and off when
it is not: no parameter value switches it off. At controller construction
every rule is *bound* (:meth:`Rule.bind`) to a :class:`RuleContext`, giving a
:class:`RuleInstance` that holds the per-controller state and implements some
of the hooks at the engine's natural seams, in the order the pipeline calls
them (:meth:`sqpmpc.control.pipeline.ControllerPipeline.step`):

1. :meth:`RuleInstance.configure_rows` (once, at construction): shape the
   collision-row geometry the compiled kernels build (:class:`RowGeometry`);
2. :meth:`RuleInstance.shape_references`: change the references of a sample
   (:attr:`SampleView.references`) or the cost weights;
3. :meth:`RuleInstance.shape_guess`: change the linearization point
   (the speeds of the shifted guess, a view into the iterate);
4. :meth:`RuleInstance.after_solve`: ask for the sample to be iterated to
   convergence (SQP) after the RTI step;
5. :meth:`RuleInstance.counters`: what the rule did, as named integer counts;
6. :meth:`RuleInstance.references_changed`: a reference was replaced between
   samples (:meth:`sqpmpc.control.pipeline.ControllerPipeline.update_reference`).

Only the hooks a rule overrides are called. Rules never touch safety: the
collision rows stay inner approximations with a hard stage 1 whatever the
geometry, and every first input is verified before it is applied; a rule
changes *which* safe motion the controller picks. The registry of the
built-in rules is :mod:`sqpmpc.rules.registry`; their implementations are in
:mod:`sqpmpc.rules.liveness`.
"""

from __future__ import annotations

import dataclasses
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.ocp.geometry import RowGeometry

if TYPE_CHECKING:
    from sqpmpc.ocp.iteration import MultipleShootingSQP
    from sqpmpc.problem.scenario import Scenario

__all__ = ["Rule", "RuleContext", "RuleInstance", "RowGeometry", "SampleView", "check_positive"]


@dataclass
class RuleContext:
    """What a rule may use, for one controller (built once by the pipeline).

    Attributes
    ----------
    scenario
        The problem.
    own
        ``(m,)`` scenario indices of the robots this controller drives.
    scheme
        ``"centralized"`` or ``"decentralized"``.
    iteration_scheme
        ``"rti"`` or ``"sqp"``.
    engine
        The controller's iteration engine (cost weights, iterate, multipliers).
    geometry
        Collision-row geometry, shaped by :meth:`RuleInstance.configure_rows`.
    counts
        The controller's counters (one dict for the engine and every rule, so
        that a sample's snapshot is one copy); rules add their own keys.
    """

    scenario: Scenario
    own: np.ndarray
    scheme: str
    iteration_scheme: str
    engine: MultipleShootingSQP
    geometry: RowGeometry
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def horizon(self) -> int:
        """``N``."""
        return self.scenario.horizon

    @property
    def sample_time(self) -> float:
        """``Ts``, s."""
        return self.scenario.sample_time

    def speed_within_bounds(self, speed: float) -> float:
        """``speed`` clipped to the bounds of ``v``, m/s."""
        b = self.scenario.bounds
        return float(np.clip(speed, b.input_lower()[0], b.input_upper()[0]))

    @property
    def max_speed(self) -> float:
        """Largest ``|v|`` the bounds allow, m/s."""
        b = self.scenario.bounds
        return float(max(abs(b.input_lower()[0]), abs(b.input_upper()[0])))


@dataclass
class SampleView:
    """One sample as the rules see it (owned and filled by the pipeline).

    Attributes
    ----------
    sample, t
        Sample index ``k`` and time ``t_k``.
    positions
        ``(n, 2)`` measured positions of all robots (scenario order).
    own_states
        ``(m, 3)`` measured states of the own robots.
    scenario_references
        ``(m, N, 2)`` the scenario's references of stages 1..N.
    references
        ``(m, N, 2)`` the references the QP will track; a rule may replace it.
    applied, applied_before
        ``(m, 2)`` inputs applied at samples ``k-1`` and ``k-2`` (zeros before).
    headings
        ``(n,)`` measured headings of all robots, rad (``None``: not known).
    """

    sample: int
    t: float
    positions: np.ndarray
    own_states: np.ndarray
    scenario_references: np.ndarray
    references: np.ndarray
    applied: np.ndarray
    applied_before: np.ndarray
    headings: np.ndarray | None = None


class RuleInstance:
    """A rule bound to one controller: its state and its hooks (no-ops here).

    ``counter_names`` declares the rule's counters; they start at 0 in the
    controller's ``context.counts``, which the hooks increment.
    """

    counter_names: tuple[str, ...] = ()

    def __init__(self, rule: Rule, context: RuleContext) -> None:
        self.rule = rule
        self.context = context
        self.counts = context.counts
        for name in self.counter_names:
            self.counts.setdefault(name, 0)

    def configure_rows(self, geometry: RowGeometry) -> None:
        """Shape the collision-row geometry (called once, at construction)."""

    def references_changed(self) -> None:
        """``context.scenario``'s references changed: refresh what was derived from them."""

    def shape_references(self, view: SampleView) -> None:
        """Change ``view.references`` (or the cost weights) for this sample."""

    def shape_guess(self, view: SampleView, speeds: np.ndarray) -> None:
        """Change the linearization speeds ``(m, N)`` (a writable view of the guess)."""

    def after_solve(self, view: SampleView) -> bool:
        """Whether this sample must be iterated to convergence after the RTI step."""
        return False

    def counters(self) -> Mapping[str, int]:
        """Named counts of what the rule did so far."""
        return {name: self.counts[name] for name in self.counter_names}


@dataclass(frozen=True)
class Rule:
    """Base of every rule: a frozen dataclass of validated parameters.

    Subclasses set the class attributes ``name`` (the registry key, kebab
    case), ``summary`` (one line for ``sqpmpc rules``), ``requires`` (names
    of rules that must also be in the list) and ``instance`` (their
    :class:`RuleInstance` subclass), and validate their fields in
    ``__post_init__`` with :func:`check_positive`.
    """

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    requires: ClassVar[tuple[str, ...]] = ()
    instance: ClassVar[type[RuleInstance]] = RuleInstance

    def bind(self, context: RuleContext) -> RuleInstance:
        """This rule's state and hooks for one controller."""
        return self.instance(self, context)

    def parameters(self) -> dict[str, object]:
        """The rule's parameters by name."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


def check_positive(rule: Rule, *names: str, allow_zero: bool = False) -> None:
    """Refuse non-finite or non-positive parameters, naming the rule and the field."""
    for name in names:
        value = getattr(rule, name)
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_) and bool(
            np.isfinite(value)) and (value >= 0 if allow_zero else value > 0)
        if not ok:
            bound = ">= 0" if allow_zero else "> 0"
            raise ProblemError(f"rule {rule.name!r}: {name} must be finite and {bound}, "
                               f"got {value!r}")
