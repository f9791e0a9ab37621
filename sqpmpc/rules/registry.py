"""The registry of rules: names, defaults, selection and the always-on safety rows.

Every place that turns rules on or off (``SolverSettings.rules``, the
``--rules``/``--without`` options of every command, the services, the
benchmarks' "rules off") goes through :func:`select_rules`.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

from sqpmpc.coordination.roadmap import on_one_lattice
from sqpmpc.errors import ProblemError
from sqpmpc.problem.references import PointReference
from sqpmpc.rules.base import Rule
from sqpmpc.rules.coordination import Coordination
from sqpmpc.rules.formations import Yield
from sqpmpc.rules.liveness import (
    Detour,
    GearCycle,
    KeepRight,
    Parking,
    StallRepair,
    TouchingPairs,
    TurnLimit,
)
from sqpmpc.rules.roundabout import Roundabout, crowd_without_room
from sqpmpc.rules.routes import RouteFollowing

if TYPE_CHECKING:
    from sqpmpc.problem.scenario import Scenario

__all__ = [
    "OPT_IN",
    "RULES",
    "default_names",
    "roadmap_is_exact",
    "SAFETY_ROWS",
    "add_rule_arguments",
    "check_rules",
    "rule_arguments",
    "rules_from_arguments",
    "set_rule_parameters",
    "default_rules",
    "describe_rules",
    "rule_names",
    "select_rules",
]

#: Built-in rules in the order the pipeline applies them within a hook.
RULES: dict[str, type[Rule]] = {
    cls.name: cls
    for cls in (TurnLimit, KeepRight, TouchingPairs, Coordination, RouteFollowing, Yield,
                Roundabout, Detour, Parking, StallRepair, GearCycle)
}

#: Registered rules that are off unless named (``--rules``), the roadmap is exact or a
#: crowd has no room for the roundabout's ring (:func:`default_names`): in open space the
#: roadmap coordination is opt-in until it brings every robot home as fast as the rules
#: do (docs/coordination.md).
OPT_IN: tuple[str, ...] = ("coordination",)

#: The safety rows: always on, not rules (see :mod:`sqpmpc.ocp.collision_rows`).
SAFETY_ROWS: dict[str, str] = {
    "inner-approximation": "rows are separating hyperplanes n'(p_j - p_l) >= d: they imply "
                           "the distance",
    "stage-one-override": "a stage-1 row that the current positions violate uses their "
                          "normal: stopping stays feasible",
    "missing-neighbour-reach": "a neighbour without a fresh plan: stage 1 keeps d plus its "
                               "one-sample reach",
}


def rule_names() -> list[str]:
    """Names of the built-in rules, in pipeline order."""
    return list(RULES)


def default_names(scenario: Scenario | None = None) -> list[str]:
    """Names of the rules on by default, in order: the ``coordination`` rule alone for a
    scenario whose roadmap is exact (:func:`roadmap_is_exact`) or whose robots crowd
    where the roundabout has no room to pass them
    (:func:`sqpmpc.rules.roundabout.crowd_without_room`, goals at rest); for any other
    (and without a scenario) every built-in rule but :data:`OPT_IN`."""
    if scenario is not None and (roadmap_is_exact(scenario) or (
            _plannable(scenario) and crowd_without_room(scenario))):
        return ["coordination"]
    return [name for name in RULES if name not in OPT_IN]


def _plannable(scenario: Scenario) -> bool:
    """A fleet whose robots all have goals at rest among obstacles that do not move: what
    the roadmap plans."""
    return (scenario.n_robots >= 2
            and all(ob.velocity == (0.0, 0.0) for ob in scenario.obstacles)
            and all(isinstance(r.reference, PointReference) for r in scenario.robots))


def roadmap_is_exact(scenario: Scenario) -> bool:
    """Whether the scenario's robots move on a roadmap whose vertices are their own starts
    and goals: it declares the grid (``[roadmap]``, :class:`sqpmpc.problem.grid.GridSpec`:
    ``sqpmpc generate mapf``), or it is a fleet (two robots or more) whose robots all have
    goals at rest (``point`` references) among obstacles that do not move (the roadmap is
    of the static free space) and whose starts and goals lie on one grid fitted to them
    (:func:`sqpmpc.coordination.roadmap.on_one_lattice`: grid formations, a room's doorway
    places). One robot's start and goal always lie on some grid: for it the roadmap would
    only bend a straight way. Walls drawn on a grid
    (:func:`sqpmpc.coordination.roadmap.drawn_grid`) give the roadmap its cells once
    coordination is on, but do not turn it on (docs/coordination.md).
    """
    if scenario.roadmap is not None:
        return True
    if not _plannable(scenario):
        return False
    return on_one_lattice(scenario.initial_states()[:, :2], scenario.reference_positions(0.0),
                          float(scenario.required_distances().max(initial=0.0)),
                          float(scenario.diameters().max()))


def default_rules(scenario: Scenario | None = None) -> tuple[Rule, ...]:
    """The rules on by default (:func:`default_names`), with their default parameters."""
    return tuple(RULES[name]() for name in default_names(scenario))


def check_rules(rules: Sequence[Rule]) -> tuple[Rule, ...]:
    """Validate a rule list: rules only, each name once, every requirement present.

    Returns the rules in pipeline order (registry order, then unknown
    user-defined rules in the given order).
    """
    seen: dict[str, Rule] = {}
    for rule in rules:
        if not isinstance(rule, Rule):
            raise ProblemError(f"rules must be Rule instances, got {type(rule).__name__}")
        if not rule.name:
            raise ProblemError(f"rule {type(rule).__name__} has no name")
        if rule.name in seen:
            raise ProblemError(f"rule {rule.name!r} is listed twice")
        seen[rule.name] = rule
    for rule in seen.values():
        missing = [r for r in rule.requires if r not in seen]
        if missing:
            raise ProblemError(f"rule {rule.name!r} requires {', '.join(map(repr, missing))}, "
                               f"which is not in the rule list")
    order = {name: i for i, name in enumerate(RULES)}
    return tuple(sorted(seen.values(), key=lambda r: order.get(r.name, len(order))))


def select_rules(names: Iterable[str] | None = None, without: Iterable[str] = (),
                 option: str = "--rules", scenario: Scenario | None = None
                 ) -> tuple[Rule, ...]:
    """The default-parameter rules named in ``names`` (all if ``None``) minus ``without``.

    ``option`` names the user-facing option in error messages. ``"none"`` as
    the only name selects no rule. ``None`` selects the rules on by default (for
    ``scenario``: :func:`default_names`).
    """
    chosen = default_names(scenario) if names is None else [n.strip() for n in names if n.strip()]
    if chosen == ["none"]:
        chosen = []
    without = [n.strip() for n in without if n.strip()]
    for name, where in [(n, option) for n in chosen] + [(n, "--without") for n in without]:
        if name not in RULES:
            raise ProblemError(f"{where}: unknown rule {name!r}; the rules are "
                               f"{', '.join(RULES)} (see 'sqpmpc rules')")
    return check_rules([RULES[n]() for n in chosen if n not in without])


def describe_rules() -> str:
    """One line per rule and per safety row (``sqpmpc rules``)."""
    width = max(map(len, list(RULES) + list(SAFETY_ROWS)))
    lines = ["rules (on by default but those marked opt-in; a scenario that declares its "
             "[roadmap], or whose robots' starts and goals lie on one grid, runs with "
             "coordination alone; remove one with --without NAME, choose with --rules A,B):"]
    lines += [f"  {name:<{width}}  {'(opt-in) ' if name in OPT_IN else ''}{cls.summary}"
              for name, cls in RULES.items()]
    lines.append("safety rows (always on):")
    lines += [f"  {name:<{width}}  {text}" for name, text in SAFETY_ROWS.items()]
    return "\n".join(lines)


def set_rule_parameters(rules: Sequence[Rule], assignments: Iterable[str],
                        option: str = "--rule-param") -> tuple[Rule, ...]:
    """Rules with parameters changed by ``RULE.FIELD=VALUE`` assignments (validated).

    The value is parsed as the field's current type (int, float or bool).
    """
    by_name = {r.name: r for r in rules}
    for text in assignments:
        target, sep, raw = text.partition("=")
        rule_name, dot, field = target.strip().partition(".")
        if not sep or not dot:
            raise ProblemError(f"{option}: expected RULE.FIELD=VALUE, got {text!r}")
        if rule_name not in by_name:
            raise ProblemError(f"{option}: rule {rule_name!r} is not on (rules on: "
                               f"{', '.join(by_name) or 'none'})")
        rule = by_name[rule_name]
        fields = rule.parameters()
        if field not in fields:
            raise ProblemError(f"{option}: rule {rule_name!r} has no parameter {field!r} "
                               f"(parameters: {', '.join(fields) or 'none'})")
        current = fields[field]
        try:
            if isinstance(current, bool):
                if raw.strip().lower() not in ("true", "false"):
                    raise ValueError(raw)
                value: object = raw.strip().lower() == "true"
            else:
                value = type(current)(raw)
        except ValueError:
            raise ProblemError(f"{option}: {rule_name}.{field} must be a "
                               f"{type(current).__name__}, got {raw!r}") from None
        by_name[rule_name] = dataclasses.replace(rule, **{field: value})
    return check_rules(list(by_name.values()))


def add_rule_arguments(parser: argparse.ArgumentParser) -> None:
    """The rule options every command takes (read by :func:`rules_from_arguments`)."""
    group = parser.add_argument_group("rules (sqpmpc rules lists them)")
    group.add_argument("--rules", default=None, metavar="NAME,NAME",
                       help="the liveness rules to use, comma-separated, or 'none' "
                            "(default: coordination alone where the scenario's roadmap is "
                            "exact, a declared grid or a fleet on one grid; else every rule "
                            "but the opt-in ones)")
    group.add_argument("--without", action="append", default=[], metavar="NAME",
                       help="remove one rule (repeatable)")
    group.add_argument("--rule-param", action="append", default=[], metavar="RULE.FIELD=VALUE",
                       help="set a rule's parameter, e.g. keep-right.angle=0.1 (repeatable)")


def rules_from_arguments(args: argparse.Namespace, scenario: Scenario | None = None
                         ) -> tuple[Rule, ...]:
    """The rules chosen by :func:`add_rule_arguments`' options (defaults: for ``scenario``)."""
    names = None if args.rules is None else args.rules.split(",")
    rules = select_rules(names, args.without, option="--rules", scenario=scenario)
    return set_rule_parameters(rules, args.rule_param)


def rule_arguments(args: argparse.Namespace) -> list[str]:
    """The rule options of ``args`` as command-line words (to hand to a child process)."""
    words: list[str] = [] if args.rules is None else ["--rules", args.rules]
    for name in args.without:
        words += ["--without", name]
    for text in args.rule_param:
        words += ["--rule-param", text]
    return words
