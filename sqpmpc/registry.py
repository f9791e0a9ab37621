"""The registry of rules: names, defaults, selection and the always-on safety rows.

Every place that turns rules on or off (``SolverSettings.rules``, the
``--rules``/``--without`` options of every command, the services, the
benchmarks' "rules off") goes through :func:`select_rules`.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from .errors import ProblemError
from .liveness import Detour, GearCycle, KeepRight, Parking, StallRepair, TouchingPairs, TurnLimit
from .rules import Rule

__all__ = [
    "RULES",
    "SAFETY_ROWS",
    "check_rules",
    "default_rules",
    "describe_rules",
    "rule_names",
    "select_rules",
]

#: Built-in rules in the order the pipeline applies them within a hook.
RULES: dict[str, type[Rule]] = {
    cls.name: cls
    for cls in (TurnLimit, KeepRight, TouchingPairs, Detour, Parking, StallRepair, GearCycle)
}

#: The safety rows: always on, not rules (see :mod:`sqpmpc.collision`).
SAFETY_ROWS: dict[str, str] = {
    "inner-approximation": "every collision row is a separating hyperplane n'(p_j - p_l) >= d, "
                           "which implies the true distance",
    "stage-one-override": "a stage-1 normal that would make the current configuration "
                          "infeasible is replaced by the current one: stopping stays feasible",
    "missing-neighbour-reach": "a neighbour without a fresh plan is kept at d plus what it "
                               "can travel in one sample on stage 1 (or not approached)",
}


def rule_names() -> list[str]:
    """Names of the built-in rules, in pipeline order."""
    return list(RULES)


def default_rules() -> tuple[Rule, ...]:
    """Every built-in rule with its default parameters."""
    return tuple(cls() for cls in RULES.values())


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
                 option: str = "--rules") -> tuple[Rule, ...]:
    """The default-parameter rules named in ``names`` (all if ``None``) minus ``without``.

    ``option`` names the user-facing option in error messages. ``"none"`` as
    the only name selects no rule.
    """
    chosen = list(RULES) if names is None else [n.strip() for n in names if n.strip()]
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
    lines = ["rules (on by default; remove one with --without NAME):"]
    lines += [f"  {name:<{width}}  {cls.summary}" for name, cls in RULES.items()]
    lines.append("safety rows (always on):")
    lines += [f"  {name:<{width}}  {text}" for name, text in SAFETY_ROWS.items()]
    return "\n".join(lines)
