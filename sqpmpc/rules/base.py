r"""The rule interface: liveness heuristics as named plug-ins of the per-sample pipeline.

A *rule* is a frozen, validated dataclass holding its own parameters. A rule
is on when it is in :attr:`sqpmpc.control.settings.SolverSettings.rules` and off when
it is not: no parameter value switches it off. At controller construction
every rule is *bound* (:meth:`Rule.bind`) to a :class:`RuleContext`, giving a
:class:`RuleInstance` that holds the per-controller state and declares, in
:attr:`RuleInstance.hooks`, which of the hooks below the pipeline calls, in
the order of :meth:`sqpmpc.control.pipeline.ControllerPipeline.run_sample`:

1. ``"rows"`` :meth:`RuleInstance.configure_rows` (once, at construction):
   returns the collision-row geometry the compiled kernels build
   (:class:`RowGeometry`);
2. ``"references"`` :meth:`RuleInstance.shape_references`: may return new
   references of the sample or a scale of the position weights;
3. ``"guess"`` :meth:`RuleInstance.shape_guess`: may return new speeds of the
   linearization point (:attr:`SampleView.guess_speeds`);
4. ``"after_solve"`` :meth:`RuleInstance.after_solve`: may ask for the sample
   to be iterated to convergence (SQP) after the RTI step.

Data flows one way. A hook reads one :class:`SampleView`, whose arrays are
read-only, and returns a :class:`Contribution` (or ``None``: nothing to
change); the pipeline applies it through the engine's public update methods
and hands the next rule a view with it. A rule never holds the engine or a
writable view of its arrays; what it keeps is its own state and its counters
(:meth:`RuleInstance.counters`, in the controller's ``context.counts``).
:meth:`RuleInstance.references_changed` tells it a reference was replaced
between samples (:meth:`sqpmpc.control.pipeline.ControllerPipeline.update_reference`).

Rules never touch safety: the collision rows stay inner approximations with
a hard stage 1 whatever the geometry, and every first input is verified
before it is applied; a rule changes *which* safe motion the controller
picks. The registry of the built-in rules is :mod:`sqpmpc.rules.registry`;
their implementations are in :mod:`sqpmpc.rules.liveness`.
"""

from __future__ import annotations

import dataclasses
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.ocp.geometry import RowGeometry

if TYPE_CHECKING:
    from sqpmpc.problem.scenario import Scenario

__all__ = [
    "HOOKS", "Contribution", "Rule", "RuleContext", "RuleInstance", "RowGeometry", "SampleView",
    "check_positive", "read_only",
]


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
    counts
        The controller's counters (one dict for the engine and every rule, so
        that a sample's snapshot is one copy); rules add their own keys.
    model_margin
        Distance, m, the collision rows of robots with velocity states
        (acceleration bounds) keep beyond the required distances
        (:func:`sqpmpc.problem.plant.model_margin`: 0.5 m between two robots
        declaring accelerations of 2 m/s^2 at ``Ts`` = 0.5 s); 0 for the
        paper's robot. Two such robots never come closer than the required
        distance plus this, more than the ``detour`` rule's ``reach`` (0.3 m),
        so a rule that asks whether a neighbour is *near* (``detour``) or how
        far to keep around a crowd (``roundabout``) adds it. The paper's robot
        on an inexact plant keeps a smaller margin (0.119 m on the exact
        plant), within ``reach``: its rules measure from the required distance
        as tuned (measured with the margin added there: costs changed both
        ways, e.g. crossing-4 centralized -29 %, swap-6 decentralized +14 %).
    obstacle_margin
        Distance, m, the rows against static obstacles and walls keep beyond the
        robot's radius for the plant's deviation from the prediction: half the
        pipeline's model margin (0.125 m with acceleration limits [-1, 1] m/s^2 and [-3, 3] rad/s^2,
        Ts 0.5 s; 0 for the paper's robot on the Euler plant). The rows add
        the solver's ``collision_margin`` (1 mm) on top. A straight way nearer a wall
        than this is one the QP will not take (the ``route`` rule only heads for
        points reachable with it).
    pair_margin
        Distance, m, the collision rows between two robots at rest keep beyond the
        required distance: the solver's ``collision_margin`` plus the plant's model
        margin, or for robots with velocity states what this scheme's rows keep
        (:attr:`sqpmpc.problem.margins.RowMargins.kept`, the same in both schemes:
        0.19 m at accelerations of 3 m/s^2 and ``Ts`` = 0.5 s).
    wall_margin
        Distance, m, the rows against the static map keep beyond the robot's radius
        (the solver's ``collision_margin`` plus :attr:`obstacle_margin`).
    departed
        Scenario indices of the robots whose controllers left the run for good
        (:meth:`sqpmpc.control.pipeline.ControllerPipeline.update_departed`): they stand
        where they are from now on.
    """

    scenario: Scenario
    own: np.ndarray
    scheme: str
    iteration_scheme: str
    counts: dict[str, int] = field(default_factory=dict)
    model_margin: float = 0.0
    obstacle_margin: float = 0.0
    pair_margin: float = 0.0
    wall_margin: float = 0.0
    departed: frozenset[int] = frozenset()

    def kept_distances(self) -> np.ndarray:
        """``(m, n)`` distances the rows keep from the own robots to everyone, m: the
        required distances plus :attr:`model_margin` (zero to itself)."""
        required = self.scenario.required_distances()[self.own]
        if self.model_margin == 0.0:
            return required
        out = required + self.model_margin
        out[np.arange(self.own.size), self.own] = 0.0
        return out

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


def read_only(array: np.ndarray | None) -> np.ndarray | None:
    """A view of ``array`` that cannot be written (``None`` stays ``None``)."""
    if array is None:
        return None
    out = array.view()
    out.setflags(write=False)
    return out


_ARRAYS = ("positions", "own_states", "scenario_references", "references", "applied",
           "applied_before", "headings", "guess_speeds", "first_speeds")


@dataclass(frozen=True)
class SampleView:
    """One sample as the rules see it: frozen, every array read-only.

    The pipeline builds it after the measurement and replaces it (a new view)
    when a contribution changed what it shows; the fields of later steps are
    ``None`` before them. Its arrays hold for the sample: the pipeline refreshes
    the measurement's in place at the next one (a rule copies what it keeps).

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
        ``(m, N, 2)`` the references the QP will track (the earlier rules'
        contributions applied).
    applied, applied_before
        ``(m, 2)`` inputs applied at samples ``k-1`` and ``k-2`` (zeros before).
    headings
        ``(n,)`` measured headings of all robots, rad (``None``: not known).
    guess_speeds
        ``(m, N)`` speeds of the linearization point (the shifted guess), from
        the ``"guess"`` hooks on.
    first_speeds
        ``(m,)`` first planned speed of each own robot in the solution, in the
        ``"after_solve"`` hooks.
    holding
        In the ``"after_solve"`` hooks: called, the ``(m,)`` bool array of the
        own robots a collision row holds in the solution (``|y| > 1e-4`` on one
        of their rows), computed on demand (:meth:`engaged`).
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
    guess_speeds: np.ndarray | None = None
    first_speeds: np.ndarray | None = None
    holding: Callable[[], np.ndarray] | None = None

    def __post_init__(self) -> None:
        fields = self.__dict__  # a frozen instance: its arrays become read-only views here
        for name in _ARRAYS:
            value = fields[name]
            if value is not None and value.flags.writeable:
                fields[name] = read_only(value)

    @classmethod
    def of_sample(cls, sample: int, t: float, positions: np.ndarray, own_states: np.ndarray,
                  references: np.ndarray, applied: np.ndarray, applied_before: np.ndarray,
                  headings: np.ndarray | None, guess_speeds: np.ndarray | None
                  ) -> SampleView:
        """The view of a sample as the pipeline builds it, once per sample and controller,
        from arrays that are already read-only (not checked again: the pipeline's hot
        path); the scenario's references are also the references the QP tracks until a
        rule changes them."""
        view = object.__new__(cls)
        view.__dict__.update(
            sample=sample, t=t, positions=positions, own_states=own_states,
            scenario_references=references, references=references, applied=applied,
            applied_before=applied_before, headings=headings, guess_speeds=guess_speeds,
            first_speeds=None, holding=None)
        return view

    def solved(self, first_speeds: np.ndarray, holding: Callable[[], np.ndarray]
               ) -> SampleView:
        """This view after the solve, for the ``"after_solve"`` hooks (the pipeline's hot
        path: ``first_speeds`` is a new array of the solution, made read-only here)."""
        first_speeds.setflags(write=False)
        view = object.__new__(SampleView)
        fields = view.__dict__
        fields.update(self.__dict__)
        fields["first_speeds"] = first_speeds
        fields["holding"] = holding
        return view

    def engaged(self) -> np.ndarray:
        """``(m,)`` bool, read-only: own robots a collision row holds in the solution."""
        if self.holding is None:
            raise ProblemError("SampleView.engaged: only known after the solve")
        return read_only(self.holding())

    def but(self, **changes: object) -> SampleView:
        """This view with ``changes`` of its fields (arrays made read-only).

        Raises
        ------
        ProblemError
            A name that is not a field of the view.
        """
        if changes.keys() - _FIELDS:
            raise ProblemError(f"SampleView has no field "
                               f"{', '.join(sorted(changes.keys() - _FIELDS))}")
        new = object.__new__(SampleView)  # a copy without re-checking the unchanged arrays
        fields = new.__dict__
        fields.update(self.__dict__)
        for name, value in changes.items():
            if isinstance(value, np.ndarray) and value.flags.writeable:
                value = read_only(value)
            fields[name] = value
        return new


_FIELDS = frozenset(f.name for f in dataclasses.fields(SampleView))


@dataclass(frozen=True)
class Contribution:
    """What a hook asks the pipeline to change (``None``: leave it).

    Attributes
    ----------
    references
        ``(m, N, 2)`` new references of the sample (``"references"`` hooks).
    position_weight_scale
        ``(m,)`` factor on each own robot's position weight ``Q``, kept until
        changed again (``"references"`` hooks).
    guess_speeds
        ``(m, N)`` new speeds of the linearization point (``"guess"`` hooks); the
        pipeline applies a contribution at once, so a rule may hand out a buffer it
        reuses at the next sample.
    motions
        ``(rows (k,), poses (k, N+1, 3), velocities (k, N+1, 2))``: the own robots ``rows``
        track these motions at this sample: their inputs and velocity states become the
        references of the robots', and the motions' rollouts their linearization point
        (``"references"`` hooks;
        :meth:`~sqpmpc.models.base.RobotModel.motion_states` gives the model's states and
        inputs; :meth:`~sqpmpc.ocp.iteration.Iteration.update_motion`).
    iterate
        Iterate this sample to convergence (SQP) after the RTI step
        (``"after_solve"`` hooks).
    """

    references: np.ndarray | None = None
    position_weight_scale: np.ndarray | None = None
    guess_speeds: np.ndarray | None = None
    motions: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    iterate: bool = False


#: The hooks a :class:`RuleInstance` may declare, in the order the pipeline calls them.
HOOKS = ("rows", "references", "guess", "after_solve")


class RuleInstance:
    """A rule bound to one controller: its state and its hooks.

    ``hooks`` declares which hooks the pipeline calls (a subset of
    :data:`HOOKS`); ``counter_names`` declares the rule's counters, which
    start at 0 in the controller's ``context.counts`` and the hooks increment.
    """

    hooks: tuple[str, ...] = ()
    counter_names: tuple[str, ...] = ()
    #: ``True`` when the rule's per-sample hooks have nothing to do for this controller
    #: (no map to route on, fewer than two goals to yield to, ...): the pipeline does not
    #: call them until the references change (:meth:`references_changed` may update it)
    idle: bool = False

    def __init__(self, rule: Rule, context: RuleContext) -> None:
        unknown = set(self.hooks) - set(HOOKS)
        if unknown:
            raise ProblemError(f"rule {rule.name!r}: unknown hooks {sorted(unknown)}; "
                               f"hooks are {', '.join(HOOKS)}")
        self.rule = rule
        self.context = context
        self.counts = context.counts
        for name in self.counter_names:
            self.counts.setdefault(name, 0)

    def configure_rows(self, geometry: RowGeometry) -> RowGeometry:
        """``"rows"``: the collision-row geometry from ``geometry`` (called once)."""
        return geometry

    def references_changed(self) -> None:
        """``context.scenario``'s references changed: refresh what was derived from them."""

    def departed_changed(self) -> None:
        """``context.departed`` changed: refresh what was derived from who takes part."""

    def shape_references(self, view: SampleView) -> Contribution | None:
        """``"references"``: new references or position-weight scales for this sample."""
        return None

    def shape_guess(self, view: SampleView) -> Contribution | None:
        """``"guess"``: new linearization speeds ``(m, N)`` for this sample."""
        return None

    def after_solve(self, view: SampleView) -> Contribution | None:
        """``"after_solve"``: ``Contribution(iterate=True)`` to converge this sample."""
        return None

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
