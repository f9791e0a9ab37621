"""What the processes of one run must agree on, and how a mismatch is named.

Every process computes :func:`agreed_settings` from its scenario (with the
overrides), its scheme and its controller options (:mod:`sqpmpc.cli.options`), and
its digest (:func:`settings_digest`). The plant sends the digest with every
state; a controller whose digest differs does not step: it answers with one
``cmd`` carrying its own settings (``detail``) and exits with status 2, and the
plant, on such a ``cmd`` of its current sample (or any ``cmd`` of it carrying
another digest), logs one message naming what differs
(:func:`describe_difference`), brakes that robot at that sample, runs on to
the end and exits with status 2 (an older ``cmd`` is stale: dropped first).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping

from sqpmpc.cli.options import RunOptions
from sqpmpc.problem.scenario import Scenario
from sqpmpc.rules.base import Rule

__all__ = ["ADVICE", "agreed_settings", "describe_difference", "scenario_digest",
           "settings_digest"]

ADVICE = ("start every process of a run with the same --scenario, --settings file and "
          "controller flags")


def scenario_digest(scenario: Scenario) -> str:
    """A short digest of everything in the scenario (processes must agree on it)."""
    return hashlib.sha256(scenario.to_toml().encode()).hexdigest()[:16]


def _rule_text(rule: Rule) -> str:
    params = ",".join(f"{k}={v!r}" for k, v in rule.parameters().items())
    return f"{rule.name}({params})"


def agreed_settings(scenario: Scenario, scheme: str, options: RunOptions) -> dict[str, str]:
    """The settings every process of a run must share, as short strings by key.

    The scenario (digest, and its horizon, sample time and t_end separately so that
    a different override is named), the scheme, and the controller options with
    every ``"auto"`` resolved for this scenario and scheme.
    """
    s = options.solver_settings(scenario=scenario).resolved(
        scenario.n_robots, scheme, bool(scenario.robot_model().velocity_states))
    slots = s.neighbour_slots
    out = {
        "scenario": f"{scenario.name} (digest {scenario_digest(scenario)})",
        "scheme": scheme,
        "horizon": str(scenario.horizon),
        "sample_time": f"{scenario.sample_time:g}",
        "t_end": f"{scenario.t_end:g}",
        "iteration": s.iteration_scheme,
        "hessian": s.hessian,
        "discretization": s.discretization,
        "collision_margin": f"{s.collision_margin:g}",
        "slack_penalty": f"{s.slack_penalty:g}",
        "neighbour_slots": "all" if slots is None else str(slots),
        "qp_solver": s.qp_solver,
        "rules": " ".join(_rule_text(r) for r in s.rules) or "none",
    }
    if scheme == "decentralized":
        out["decentralized_mode"] = options.decentralized_mode
        out["all_plans"] = str(bool(options.all_plans)).lower()
    return out


def settings_digest(agreed: Mapping[str, str]) -> str:
    """A short digest of :func:`agreed_settings`."""
    text = json.dumps(dict(agreed), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def describe_difference(mine: Mapping[str, str], theirs: Mapping[str, str] | None,
                        who: str, me: str = "the plant") -> str:
    """One sentence: ``robot/2 runs with collision_margin 0.05 (the plant: 0.001): ...``."""
    if not theirs:
        return (f"{who} runs with other settings than {me} (another settings digest): "
                f"{ADVICE}")
    keys = [k for k in sorted((set(mine) | set(theirs)) - {"process"})
            if mine.get(k) != theirs.get(k)]
    overridden = {"horizon", "sample_time", "t_end"} & set(keys)
    if overridden and "scenario" in keys and (mine.get("scenario", "").split(" (")[0]
                                             == theirs.get("scenario", "").split(" (")[0]):
        keys.remove("scenario")  # the same scenario with another override: name the override
    parts = [f"{k} {theirs.get(k, '(none)')} ({me}: {mine.get(k, '(none)')})" for k in keys]
    return f"{who} runs with {', '.join(parts) or 'other settings'}: {ADVICE}"
