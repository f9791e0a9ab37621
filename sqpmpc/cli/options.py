"""The controller options every command shares: flags, settings file, overrides.

``sqpmpc run``, ``services.launch``, ``services.plant``, ``services.robot`` and
``services.central`` take the same controller options under the same names
(:func:`add_controller_options`) and the same scenario overrides
(``--horizon``, ``--sample-time``, ``--t-end``). Each can also come from a
settings file, ``--settings FILE.toml``, whose keys are the flag names without
the dashes and with underscores::

    collision_margin = 0.05
    discretization = "exact"
    iteration = "rti"             # or "sqp"
    hessian = "gauss-newton"      # or "exact"
    neighbour_slots = 8           # or "all", "auto"
    qp_solver = "osqp"
    slack_penalty = 50.0
    decentralized_mode = "shared" # or "paper"
    rules = ["keep-right", "detour"]   # or "none"
    without = ["parking"]
    rule_param = ["keep-right.angle=0.1"]
    all_plans = false
    horizon = 8
    sample_time = 0.5
    t_end = 60.0

A flag given on the command line overrides the file's key. Every value is
validated where it is read: a bad one is refused naming the flag the user
typed (``--collision-margin: expected a number >= 0, got -1``) or the key and
the file (``run.toml: collision_margin: ...``), as :class:`ProblemError`.
"""

from __future__ import annotations

import argparse
import math
import re
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

from sqpmpc.control.settings import (
    FLEET_NEIGHBOUR_SLOTS,
    FLEET_QP_SOLVER,
    FLEET_ROBOTS,
    QP_SOLVER_CHOICES,
    SolverSettings,
    neighbour_slots_argument,
)
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.models.unicycle import DISCRETIZATIONS
from sqpmpc.problem.scenario import MAX_STEPS, MIN_SAMPLE_TIME, Scenario
from sqpmpc.qp.backend import OSQPSettings
from sqpmpc.rules.base import Rule
from sqpmpc.rules.registry import RULES, select_rules, set_rule_parameters

__all__ = [
    "OVERRIDE_KEYS",
    "Parser",
    "SETTINGS_KEYS",
    "RunOptions",
    "add_controller_options",
    "add_override_options",
    "combination_problem",
    "option_words",
    "flag_type",
    "plain_text",
    "nonnegative_float",
    "nonnegative_int",
    "port_number",
    "positive_float",
    "positive_int",
    "probability",
    "resolve_options",
    "with_overrides",
]


_RST_ROLE = re.compile(r":(?:py:)?[a-z]+:`~?([^`]+)`")


def plain_text(text: str) -> str:
    """``text`` without reStructuredText markup (roles, double backticks): the help the
    user reads is taken from docstrings written for the API reference."""
    return _RST_ROLE.sub(r"\1", text).replace("``", "")


class Parser(argparse.ArgumentParser):
    """An :class:`argparse.ArgumentParser` whose errors are one line naming the flag:
    ``sqpmpc run: error: --message-drop: expected a probability in [0, 1], got 2``, and
    whose help holds no reStructuredText markup (:func:`plain_text`)."""

    def format_help(self) -> str:
        """The help, as plain text."""
        return plain_text(super().format_help())

    def error(self, message: str) -> NoReturn:
        message = message.removeprefix("argument ")
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


# ------------------------------------------------------------------------------ value types
def _number(text: object, integer: bool) -> float:
    if isinstance(text, bool):
        raise ValueError
    if isinstance(text, int | float):
        value = float(text)
    else:
        value = float(int(str(text)) if integer else float(str(text)))
    if integer and not float(value).is_integer():
        raise ValueError
    return value


def flag_type(check: Callable[[float], bool], expected: str,
              integer: bool = False) -> Callable[[object], Any]:
    """An argparse ``type`` (also used on settings-file values): a number that passes
    ``check``, else :class:`argparse.ArgumentTypeError` saying what was expected."""

    def convert(text: object) -> Any:
        try:
            value = _number(text, integer)
        except (ValueError, OverflowError):
            value = math.nan
        if not (math.isfinite(value) and check(value)):
            shown = text if isinstance(text, str) else repr(text)
            raise argparse.ArgumentTypeError(f"expected {expected}, got {shown}")
        return int(value) if integer else value

    convert.__name__ = expected  # argparse names the type in some messages
    return convert


nonnegative_float = flag_type(lambda v: v >= 0.0, "a number >= 0")
positive_float = flag_type(lambda v: v > 0.0, "a number > 0")
positive_int = flag_type(lambda v: v >= 1, "an integer >= 1", integer=True)
nonnegative_int = flag_type(lambda v: v >= 0, "an integer >= 0", integer=True)
port_number = flag_type(lambda v: 0 <= v <= 65535, "a port in 0..65535", integer=True)
probability = flag_type(lambda v: 0.0 <= v <= 1.0, "a probability in [0, 1]")


def _choice(choices: tuple[str, ...]) -> Callable[[object], str]:
    def convert(value: object) -> str:
        if not isinstance(value, str) or value not in choices:
            raise argparse.ArgumentTypeError(
                f"expected one of {', '.join(choices)}, got {value!r}")
        return value

    return convert


def _slots(value: object) -> int | str:
    """An integer >= 1, ``"all"`` or ``"auto"`` (``"all"`` is ``None`` in the settings)."""
    if isinstance(value, bool) or not isinstance(value, int | str):
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, 'all' or 'auto', "
                                         f"got {value!r}")
    slots = neighbour_slots_argument(str(value))
    return "all" if slots is None else slots


def _names(value: object) -> str:
    """Rule names: a comma-separated string or (file) a list of strings."""
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return ",".join(value) if value else "none"
    if isinstance(value, str):
        return value
    raise argparse.ArgumentTypeError(f"expected a list of rule names or 'none', got {value!r}")


def _strings(value: object) -> list[str]:
    if isinstance(value, str):
        return [value]
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return list(value)
    raise argparse.ArgumentTypeError(f"expected a list of strings, got {value!r}")


def _assignments(value: object) -> list[str]:
    """``rule_param``: a list of ``RULE.FIELD=VALUE`` or a table ``{"RULE.FIELD" = VALUE}``."""
    if isinstance(value, dict):
        return [f"{k}={str(v).lower() if isinstance(v, bool) else v}" for k, v in value.items()]
    return _strings(value)


def _flag(value: object) -> bool:
    if not isinstance(value, bool):
        raise argparse.ArgumentTypeError(f"expected true or false, got {value!r}")
    return value


_MAX_T = flag_type(lambda v: v > 0.0, "a number > 0 (s)")
_TS = flag_type(lambda v: v >= MIN_SAMPLE_TIME, f"a number >= {MIN_SAMPLE_TIME:g} (s)")

#: Settings-file keys and how their values are read (the flags' ``type``).
SETTINGS_KEYS: dict[str, Callable[[object], Any]] = {
    "decentralized_mode": _choice(("shared", "paper")),
    "iteration": _choice(("rti", "sqp")),
    "hessian": _choice(("gauss-newton", "exact")),
    "discretization": _choice(DISCRETIZATIONS),
    "neighbour_slots": _slots,
    "qp_solver": _choice(QP_SOLVER_CHOICES),
    "collision_margin": nonnegative_float,
    "slack_penalty": nonnegative_float,
    "rules": _names,
    "without": _strings,
    "rule_param": _assignments,
    "all_plans": _flag,
    "horizon": positive_int,
    "sample_time": _TS,
    "t_end": _MAX_T,
}
#: The scenario overrides among :data:`SETTINGS_KEYS`.
OVERRIDE_KEYS = ("horizon", "sample_time", "t_end")
_DEFAULTS: dict[str, Any] = {"decentralized_mode": "shared", "iteration": "rti",
                             "hessian": "gauss-newton", "discretization": "euler",
                             "neighbour_slots": "auto", "qp_solver": "auto",
                             "collision_margin": SolverSettings.collision_margin,
                             "slack_penalty": SolverSettings.slack_penalty, "rules": None,
                             "without": [], "rule_param": [], "all_plans": False,
                             "horizon": None, "sample_time": None, "t_end": None}


def _flag_name(key: str) -> str:
    return "--" + key.replace("_", "-")


def add_controller_options(parser: argparse.ArgumentParser, *, decentralized: bool = True,
                           all_plans: bool = False, overrides: bool = True) -> None:
    """Add ``--settings``, the controller options and the scenario overrides to ``parser``.

    Every default is ``None`` (read by :func:`resolve_options`, which applies the
    settings file and the library defaults). ``decentralized``: also
    ``--decentralized-mode``; ``all_plans``: also ``--all-plans`` (the robots');
    ``overrides``: also ``--horizon``, ``--sample-time``, ``--t-end``.
    """
    group = parser.add_argument_group(
        "controller settings (the same in every process of a run; also from --settings)")
    group.add_argument("--settings", type=Path, default=None, metavar="FILE.toml",
                       help="read these options from a TOML file (keys: the flag names with "
                            "underscores, e.g. collision_margin = 0.05); flags override it")
    if decentralized:
        group.add_argument("--decentralized-mode", type=SETTINGS_KEYS["decentralized_mode"],
                           metavar="shared|paper",
                           help="decentralized: shared-responsibility hyperplanes (default) "
                                "or the paper's literal scheme")
    group.add_argument("--iteration", type=SETTINGS_KEYS["iteration"], metavar="rti|sqp",
                       help="one QP per sample (rti, default) or SQP to convergence")
    group.add_argument("--hessian", type=SETTINGS_KEYS["hessian"],
                       metavar="gauss-newton|exact", help="default gauss-newton")
    group.add_argument("--discretization", type=SETTINGS_KEYS["discretization"],
                       metavar="|".join(DISCRETIZATIONS),
                       help="prediction model (default euler)")
    group.add_argument("--neighbour-slots", type=_slots, metavar="N|all|auto",
                       help="collision slots per robot, filled with the nearest neighbours "
                            "within reach; 'all': one per other robot; 'auto' (default): "
                            f"{FLEET_NEIGHBOUR_SLOTS} on fleets of more than {FLEET_ROBOTS} "
                            "robots, else all")
    group.add_argument("--qp-solver", type=SETTINGS_KEYS["qp_solver"],
                       metavar="|".join(QP_SOLVER_CHOICES),
                       help=f"QP backend; 'auto' (default): {FLEET_QP_SOLVER} for the "
                            f"decentralized robots of fleets of more than {FLEET_ROBOTS}, "
                            f"active-set for the centralized QP of at most {FLEET_ROBOTS} "
                            "robots without velocity states, "
                            "else osqp+piqp: OSQP capped at the hand-over, PIQP for the "
                            "rest (docs/qp-backends.md, docs/speed.md)")
    group.add_argument("--collision-margin", type=nonnegative_float, metavar="M",
                       help="added to every required distance in the QP, m (default "
                            f"{SolverSettings.collision_margin:g}); raise it to cover a plant "
                            "that differs from the prediction model")
    group.add_argument("--slack-penalty", type=nonnegative_float, metavar="P",
                       help="L1 price of collision slacks on stages 2..N (default "
                            f"{SolverSettings.slack_penalty:g})")
    group.add_argument("--rules", default=None, metavar="NAME,NAME",
                       help="the liveness rules, comma-separated, or 'none' (default: all; "
                            "sqpmpc rules lists them)")
    group.add_argument("--without", action="append", default=None, metavar="NAME",
                       help="remove one rule (repeatable)")
    group.add_argument("--rule-param", action="append", default=None,
                       metavar="RULE.FIELD=VALUE",
                       help="set a rule's parameter, e.g. keep-right.angle=0.1 (repeatable)")
    if all_plans:
        group.add_argument("--all-plans", action="store_true", default=None,
                           help="with neighbour slots: every robot receives, decodes and "
                                "waits for every neighbour's plan (default: only of those "
                                "that may take one of its slots, services.plans)")
    if overrides:
        add_override_options(group)


def add_override_options(parser: argparse.ArgumentParser | Any) -> None:
    """``--horizon``, ``--sample-time``, ``--t-end`` (defaults ``None``; read by
    :func:`with_overrides`); ``parser`` may be an argument group."""
    parser.add_argument("--horizon", type=positive_int, metavar="N",
                        help="override the scenario's horizon N")
    parser.add_argument("--sample-time", type=_TS, metavar="TS",
                        help="override the scenario's sample time Ts, s (t_end stays a "
                             "whole number of samples)")
    parser.add_argument("--t-end", type=_MAX_T, metavar="T",
                        help="override the scenario's t_end, s")


@dataclass(frozen=True)
class RunOptions:
    """The controller options of one process, resolved (flags over file over defaults).

    Attributes
    ----------
    values
        Every key of :data:`SETTINGS_KEYS` with its value.
    sources
        For each key given by the user, where: ``"--collision-margin"`` or
        ``"collision_margin in run.toml"`` (named in errors).
    """

    values: dict[str, Any]
    sources: dict[str, str] = field(default_factory=dict)

    def __getattr__(self, key: str) -> Any:
        try:
            return self.__dict__["values"][key]
        except KeyError:
            raise AttributeError(key) from None

    def given(self, key: str, on_command_line: bool = True) -> bool:
        """Whether the user gave ``key`` (on the command line only, by default)."""
        source = self.sources.get(key)
        return source is not None and (not on_command_line or source.startswith("--"))

    def rules_chosen(self, scenario: Scenario | None = None) -> tuple[Rule, ...]:
        """The rules of ``rules``/``without``/``rule_param``, errors naming their source
        (the defaults: ``scenario``'s, :func:`sqpmpc.rules.registry.default_names`)."""
        v, src = self.values, self.sources
        names = None if v["rules"] is None else v["rules"].split(",")
        for name in v["without"]:
            if name.strip() not in RULES:
                raise ProblemError(f"{src.get('without', '--without')}: unknown rule "
                                   f"{name.strip()!r}; the rules are {', '.join(RULES)} "
                                   "(see 'sqpmpc rules')")
        rules = select_rules(names, v["without"], option=src.get("rules", "--rules"),
                             scenario=scenario)
        return set_rule_parameters(rules, v["rule_param"],
                                   option=src.get("rule_param", "--rule-param"))

    def solver_settings(self, time_limit: float | None = None,
                        scenario: Scenario | None = None) -> SolverSettings:
        """The :class:`SolverSettings` (``time_limit``: a bound on each QP and sample, s;
        the default rules: ``scenario``'s)."""
        v = self.values
        extra: dict[str, Any] = {}
        if time_limit:
            extra = {"time_budget": time_limit, "osqp": OSQPSettings(time_limit=time_limit)}
        return SolverSettings(iteration_scheme=v["iteration"], hessian=v["hessian"],
                              discretization=v["discretization"],
                              collision_margin=v["collision_margin"],
                              slack_penalty=v["slack_penalty"], rules=self.rules_chosen(scenario),
                              qp_solver=v["qp_solver"],
                              neighbour_slots=None if v["neighbour_slots"] == "all"
                              else v["neighbour_slots"],
                              **extra)


def _read_file(path: Path) -> dict[str, Any]:
    try:
        with path.open("rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise ProblemError(f"--settings {path}: no such file") from None
    except OSError as exc:
        raise ProblemError(f"--settings {path}: cannot read it: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ProblemError(f"{path}: not valid TOML: {exc}") from None
    out: dict[str, Any] = {}
    for key, raw in data.items():
        if key not in SETTINGS_KEYS:
            raise ProblemError(f"{path}: unknown key {key!r} (the keys are "
                               f"{', '.join(SETTINGS_KEYS)})")
        try:
            out[key] = SETTINGS_KEYS[key](raw)
        except argparse.ArgumentTypeError as exc:
            raise ProblemError(f"{path}: {key}: {exc}") from None
    return out


def resolve_options(args: argparse.Namespace) -> RunOptions:
    """The options of :func:`add_controller_options` as parsed, over ``--settings``, over
    the defaults; the rules are checked too. Raises :class:`ProblemError` naming the
    flag, or the key and the file."""
    path = getattr(args, "settings", None)
    from_file = _read_file(path) if path is not None else {}
    values = dict(_DEFAULTS)
    sources: dict[str, str] = {}
    for key, value in from_file.items():
        values[key] = value
        sources[key] = f"{key} in {path}"
    for key in SETTINGS_KEYS:
        value = getattr(args, key, None)
        if value is not None and value != []:
            if key == "rules" and isinstance(value, str):
                value = _names(value)
            values[key] = value
            sources[key] = _flag_name(key)
    options = RunOptions(values, sources)
    options.solver_settings()  # refuses bad rules now, naming their source
    return options


def with_overrides(scenario: Scenario, options: RunOptions) -> Scenario:
    """``scenario`` with the options' horizon, sample time and t_end (a new sample time
    without a new t_end keeps t_end a whole number of samples). Errors name the flag."""
    v, changes = options.values, {}
    if v["horizon"] is not None:
        changes["horizon"] = v["horizon"]
    if v["sample_time"] is not None:
        ts = v["sample_time"]
        changes["sample_time"] = ts
        if v["t_end"] is None:
            ratio = scenario.t_end / ts
            if not ratio <= MAX_STEPS:
                raise ProblemError(f"{options.sources['sample_time']}: expected a sample time "
                                   f"giving at most {MAX_STEPS} samples over t_end = "
                                   f"{scenario.t_end:g} s, got {ts!r}")
            changes["t_end"] = max(1, round(ratio)) * ts
    if v["t_end"] is not None:
        changes["t_end"] = v["t_end"]
    if not changes:
        return scenario
    try:
        return scenario.with_changes(**changes)
    except ScenarioError as exc:
        source = options.sources.get(exc.key)
        if source is None and exc.key == "t_end":
            source = options.sources.get("sample_time")
        if source is None:
            raise
        raise ProblemError(f"{source}: {exc.detail}") from None


def option_words(args: argparse.Namespace, decentralized: bool = True) -> list[str]:
    """The options of :func:`add_controller_options` as given on the command line, as
    words for a child process (``--settings`` as an absolute path); ``decentralized``:
    with the robots' options."""
    words: list[str] = []
    if getattr(args, "settings", None) is not None:
        words += ["--settings", str(Path(args.settings).resolve())]
    for key in SETTINGS_KEYS:
        value = getattr(args, key, None)
        if value is None or value == [] or (not decentralized and key in _ROBOTS_ONLY):
            continue
        flag = _flag_name(key)
        if key == "all_plans":
            words += [flag] if value else []
        elif isinstance(value, list):
            for item in value:
                words += [flag, str(item)]
        else:
            words += [flag, repr(value) if isinstance(value, float) else str(value)]
    return words


_ROBOTS_ONLY = ("decentralized_mode", "all_plans")


def combination_problem(options: RunOptions, scheme: str, n_robots: int) -> str | None:
    """Why options given on the command line do nothing with this scheme, if so."""
    if scheme == "centralized":
        for key in _ROBOTS_ONLY:
            if options.given(key):
                return f"{options.sources[key]} does nothing with --scheme centralized"
    if options.given("all_plans") and options.values["all_plans"]:
        if options.solver_settings().neighbour_slots_for(n_robots) is None:
            return (f"--all-plans does nothing without neighbour slots (the {n_robots} robots "
                    "each get a slot per other robot; see --neighbour-slots)")
    return None
