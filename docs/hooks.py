"""MkDocs hooks of the site: pages generated from the code, so that they cannot go stale.

- ``<!-- cli -->`` (``reference/cli.md``): the help of every ``sqpmpc`` command, from the
  argparse parsers themselves (:func:`cli_reference`).
- ``<!-- api: GROUP -->`` (``reference/api/*.md``): one ``::: sqpmpc.NAME`` block per
  public name of that group, from ``sqpmpc.__all__`` (:func:`api_groups`); nothing
  else of the package is documented there.
- ``<!-- api: index -->``: the table of every public name, its group and its summary.
- Every report page (:data:`REPORTS`) starts with the command that regenerates it.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import os
from collections.abc import Iterator
from typing import Any

__all__ = ["API_GROUPS", "REPORTS", "api_groups", "cli_reference", "commands",
           "on_page_markdown"]

#: Report page -> the command that regenerates it (the benchmarks write these pages).
REPORTS: dict[str, str] = {
    "benchmarks.md": "python -m benchmarks.compare_ipopt",
    "before-after.md": "python -m benchmarks.compare_ipopt --baseline PATH",
    "decomposition.md": "python -m benchmarks.decomposition",
    "liveness.md": "python -m benchmarks.liveness",
    "ablation.md": "python -m benchmarks.ablation --large",
    "random-scenarios.md": "python -m benchmarks.random_scenarios",
    "maps.md": "python -m benchmarks.maps",
    "mapf-maps.md": "python -m benchmarks.mapf_maps --maps-dir DIR",
    "qp-backends.md": "python -m benchmarks.qp_backends",
    "fleet.md": "python -m benchmarks.fleet",
    "fleet-services.md": "python -m benchmarks.fleet_services",
    "real-plants.md": "python -m benchmarks.real_plants",
    "acceleration-limits.md": "python -m benchmarks.acceleration",
    "reliability.md": "python -m benchmarks.faults && python -m benchmarks.lifecycle",
    "ros2.md": "python -m benchmarks.ros2 && python -m benchmarks.ros2_hosts",
    "physical-robots.md": "python -m benchmarks.physical",
    "speed.md": "python -m benchmarks.speed --acados-path DIR",
    "security.md": "python -m benchmarks.security",
}

#: Group of the API reference -> the subpackages of sqpmpc whose public names it holds
#: (the first group whose prefix matches a name's module takes it).
API_GROUPS: dict[str, tuple[str, ...]] = {
    "settings": ("sqpmpc.control.settings", "sqpmpc.qp", "sqpmpc.rules"),
    "scenario": ("sqpmpc.problem",),
    "controllers": ("sqpmpc.control", "sqpmpc.ocp"),
    "simulation": ("sqpmpc.sim", "sqpmpc.io"),
    "errors": ("sqpmpc.errors",),
}

#: The commands of ``sqpmpc`` whose parser lives in a service module (``services.NAME``).
_SERVICE_COMMANDS = ("launch", "plant", "robot", "central", "router", "viewer", "docker")


def api_groups() -> dict[str, list[str]]:
    """The public names (``sqpmpc.__all__`` without ``__version__``) by group of
    :data:`API_GROUPS`, in ``__all__`` order; a name of no group goes to ``"other"``."""
    sqpmpc = importlib.import_module("sqpmpc")
    groups: dict[str, list[str]] = {g: [] for g in [*API_GROUPS, "other"]}
    for name in sqpmpc.__all__:
        if name.startswith("__"):
            continue
        obj = getattr(sqpmpc, name)
        module = getattr(obj, "__module__", None) or ""
        if not (inspect.isclass(obj) or inspect.isfunction(obj)):
            module = sqpmpc._EXPORTS.get(name, "")  # a constant: where it is defined
            module = f"sqpmpc.{module}"
        group = next((g for g, prefixes in API_GROUPS.items()
                      if any(module == p or module.startswith(p + ".") for p in prefixes)),
                     "other")
        groups[group].append(name)
    return groups


def _summary(name: str) -> str:
    obj = getattr(importlib.import_module("sqpmpc"), name)
    doc = inspect.getdoc(obj) if inspect.isclass(obj) or inspect.isfunction(obj) else None
    first = (doc or "").strip().split("\n\n")[0].replace("\n", " ")
    return _plain(first).replace("|", "\\|")


def _plain(text: str) -> str:
    """reST roles and double backticks as Markdown code."""
    import re

    text = re.sub(r":(?:py:)?[a-z]+:`~?([^`]+)`", r"`\1`", text)
    return text.replace("``", "`")


def _api_index() -> str:
    rows = ["| name | page | what |", "|---|---|---|"]
    for group, names in api_groups().items():
        for name in names:
            rows.append(f"| [`sqpmpc.{name}`]({group}.md#sqpmpc.{name}) | {group} | "
                        f"{_summary(name)} |")
    return "\n".join(rows)


def _api_page(group: str) -> str:
    names = api_groups().get(group, [])
    return "\n\n".join(f"::: sqpmpc.{name}" for name in names)


def commands() -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """``(command, parser)`` of ``sqpmpc`` and of every subcommand, as the user runs them."""
    from sqpmpc.cli.main import build_parser

    root = build_parser()
    yield "sqpmpc", root
    sub = next(a for a in root._actions if isinstance(a, argparse._SubParsersAction))
    for name, parser in sub.choices.items():
        if name in _SERVICE_COMMANDS:
            module = importlib.import_module(f"services.{name}")
            yield f"sqpmpc {name}", module.build_parser(f"sqpmpc {name}")
        elif name == "credentials":
            credentials = importlib.import_module("services.credentials")
            holder = argparse.ArgumentParser(prog="sqpmpc")
            yield "sqpmpc credentials", credentials.add_parser(holder.add_subparsers())
        else:
            yield f"sqpmpc {name}", parser


def cli_reference() -> str:
    """The Markdown of every command's ``--help`` (80 columns), a section each."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "88"
    try:
        parts = []
        for command, parser in commands():
            parser.prog = command
            text = parser.format_help().rstrip()
            anchor = command.replace(" ", "-")
            parts.append(f"## `{command}` {{#{anchor}}}\n\n```text\n{text}\n```")
        return "\n\n".join(parts)
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    """Fill the markers of the page (see the module's docstring)."""
    if "<!-- cli -->" in markdown:
        markdown = markdown.replace("<!-- cli -->", cli_reference())
    if "<!-- api: index -->" in markdown:
        markdown = markdown.replace("<!-- api: index -->", _api_index())
    for group in [*API_GROUPS, "other"]:
        marker = f"<!-- api: {group} -->"
        if marker in markdown:
            markdown = markdown.replace(marker, _api_page(group))
    src = page.file.src_uri
    if src in REPORTS:
        title, _, rest = markdown.partition("\n")
        note = (f'\n\n!!! note "Regenerate this report"\n    `{REPORTS[src]}` from the '
                "repository's root (the `bench` extra installed; `make bench` runs them all).\n")
        markdown = f"{title}{note}{rest}"
    return markdown
