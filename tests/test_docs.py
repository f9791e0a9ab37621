"""The documentation site and the README: built strictly, organised, and every code block runs.

- ``docs/build.py`` (``make docs``, ``make test``) fails on a warning, ``--quiet`` too,
  where ``mkdocs build --strict --quiet`` does not.
- The navigation has the four parts (tutorial, how-to guides, reference, explanation) and
  every page of ``docs/`` is in it; the CLI reference is the parsers' help, the API
  reference exactly ``sqpmpc.__all__``; every report names the command that regenerates it.
- Every fenced code block of ``README.md`` and ``docs/``: ``python`` blocks are executed
  (a page's blocks in order, in one namespace, in a temporary folder), ``toml`` blocks
  parsed (a scenario is loaded), and every command line of ``sh``/``bash`` blocks is
  parsed by the parser of the command it names (``sqpmpc``, ``python -m services.NAME``,
  ``make TARGET``, ``docker compose -f FILE``); the cheap ones (``sqpmpc list``,
  ``generate``, ``run`` with ``--t-end``, ``metrics``, ``docker`` without ``--up``) are
  run. ``text`` blocks are output.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import re
import shlex
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import yaml

import sqpmpc
from sqpmpc.cli.main import main as sqpmpc_main
from sqpmpc.problem.scenario_file import parse_scenario

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS))
hooks = importlib.import_module("hooks")
sys.path.remove(str(DOCS))

_FENCE = re.compile(r"^```([a-z0-9]*)[^\n]*\n(.*?)^```", re.M | re.S)
PAGES = sorted([ROOT / "README.md", *DOCS.rglob("*.md")])
#: commands run for real (cheap), the others are parsed only
_RUN = ("list", "generate", "run", "metrics")


def _blocks(path: Path) -> list[tuple[str, str]]:
    return [(m.group(1), m.group(2)) for m in _FENCE.finditer(path.read_text())]


def _id(path: Path) -> str:
    return str(path.relative_to(ROOT))


# ------------------------------------------------------------------------------ the build
def _site(tmp_path: Path, page: str) -> Path:
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "index.md").write_text(page)
    config = tmp_path / "mkdocs.yml"
    config.write_text(f"site_name: t\ndocs_dir: {docs}\nsite_dir: {tmp_path / 'site'}\n"
                      "nav:\n  - index.md\n")
    return config


@pytest.mark.parametrize("quiet", [True, False], ids=["quiet", "verbose"])
def test_a_docs_warning_fails_the_build(tmp_path, quiet):
    config = _site(tmp_path, "# Home\n\nA [broken link](missing.md).\n")
    cmd = [sys.executable, str(DOCS / "build.py"), "-f", str(config),
           *(["--quiet"] if quiet else [])]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path)
    assert res.returncode == 1, res.stderr
    assert "missing.md" in res.stderr and "1 warning" in res.stderr
    # the same page without the warning builds
    (tmp_path / "docs" / "index.md").write_text("# Home\n\nNo link.\n")
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "site" / "index.html").exists()


def test_make_test_and_make_docs_build_the_site_with_the_strict_script():
    for target in ("test", "docs"):
        # a stamp that make takes as up to date (-o): `make -n` still remakes a makefile, so
        # STAMP=Makefile would create .venv and install into it when pyproject.toml is newer
        res = subprocess.run(["make", "-n", "-o", "no-such-stamp", target,
                              "STAMP=no-such-stamp"], capture_output=True, text=True, cwd=ROOT)
        assert res.returncode == 0, res.stderr
        assert "docs/build.py" in res.stdout and "mkdocs build" not in res.stdout


# ------------------------------------------------------------------------- organisation
def _nav_pages(nav: list) -> list[str]:
    out = []
    for item in nav:
        value = next(iter(item.values())) if isinstance(item, dict) else item
        out += _nav_pages(value) if isinstance(value, list) else [value]
    return out


def _config() -> dict:
    return yaml.safe_load((ROOT / "mkdocs.yml").read_text())


def test_the_navigation_holds_the_four_parts_and_every_page():
    nav = _config()["nav"]
    parts = [next(iter(item)) for item in nav]
    assert parts == ["Home", "Tutorial", "How-to guides", "Reference", "Explanation"]
    how_to = _nav_pages(nav[2]["How-to guides"])
    for topic in ("own-loop", "scenario-in-code", "maps", "services", "ros2", "security",
                  "docker", "recording"):
        assert f"how-to/{topic}.md" in how_to
    pages = set(_nav_pages(nav))
    on_disk = {str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md")}
    assert on_disk == pages  # no page built but unreachable, no nav entry without a page
    assert "tutorial/getting-started.md" in pages and "reference/cli.md" in pages


def test_the_cli_reference_is_every_parsers_help_without_markup():
    text = hooks.cli_reference()
    from sqpmpc.cli.main import build_parser

    usage = build_parser().format_usage()
    names = usage[usage.index("{") + 1:usage.index("}")].split(",")  # every subcommand
    documented = [c for c, _ in hooks.commands()][1:]
    assert len(names) >= 13 and documented == [f"sqpmpc {n}" for n in names]
    for name in names:
        assert f"## `sqpmpc {name}`" in text
        assert f"usage: sqpmpc {name}" in text
    assert "--fail-on-miss" in text and "--robots-per-process" in text
    assert not re.search(r":[a-z]+:`|``[^`]", text.replace("```", ""))


def test_the_api_reference_documents_exactly_the_public_names():
    groups = hooks.api_groups()
    names = [n for names in groups.values() for n in names]
    assert sorted(names) == sorted(n for n in sqpmpc.__all__ if not n.startswith("__"))
    assert not groups["other"], groups["other"]
    for page in (DOCS / "reference" / "api").glob("*.md"):
        assert ":::" not in page.read_text(), f"{page.name}: write no ::: by hand"


def test_every_report_names_the_command_that_regenerates_it():
    for page, command in hooks.REPORTS.items():
        assert (DOCS / page).exists(), page
        for part in command.split("&&"):
            module = part.split()[2]
            assert (ROOT / (module.replace(".", "/") + ".py")).exists(), command
    explanation = _config()["nav"][4]["Explanation"]
    reports = next(item["Reports"] for item in explanation
                   if isinstance(item, dict) and "Reports" in item)
    assert set(hooks.REPORTS) <= set(_nav_pages(reports)) | {"security.md"}


def test_the_readme_is_short_with_the_set_up_commands_and_links():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 150
    assert "make demo" in text and "make test" in text and "<img" in text
    example = [b for kind, b in _blocks(ROOT / "README.md") if kind == "python"]
    assert example and len(example[0].strip().splitlines()) <= 10


# -------------------------------------------------------------------------- code blocks
@pytest.mark.parametrize("page", [p for p in PAGES if any(
    k == "python" for k, _ in _blocks(p))], ids=_id)
def test_python_blocks_run(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__docs__"}
    for kind, code in _blocks(page):
        if kind == "python":
            exec(compile(code, f"{_id(page)}:python", "exec"), namespace)  # noqa: S102


@pytest.mark.parametrize("page", [p for p in PAGES if any(
    k == "toml" for k, _ in _blocks(p))], ids=_id)
def test_toml_blocks_parse(page):
    for kind, code in _blocks(page):
        if kind != "toml":
            continue
        data = tomllib.loads(code)
        if "robots" in data:  # a scenario: valid as one
            parse_scenario(data, source=_id(page))


def _command_lines(code: str) -> list[list[str]]:
    """The command lines of a shell block: continuations joined, comments, shell
    keywords and background ``&`` dropped, ``$i`` set to 1."""
    text = code.replace("\\\n", " ")
    out = []
    for line in text.splitlines():
        line = line.split(" #")[0].strip()
        if not line or line.startswith("#"):
            continue
        line = line.rstrip("&").strip().replace("$i", "1")
        if line.split()[0] in ("for", "done", "wait"):
            continue
        words = shlex.split(re.sub(r"\$\([^)]*\)", "X", line.removeprefix("do ")))
        while words and re.fullmatch(r"[A-Z_]+=\S*", words[0]):  # VAR=value before it
            words = words[1:]
        out.append(words)
    return out


def _parse_only(words: list[str]) -> None:
    """Parse the command line with its own parser (SystemExit: a bad flag)."""
    if words[0] == "sqpmpc":
        name = words[1]
        if name in ("launch", "plant", "robot", "central", "router", "viewer", "docker"):
            if "--ros2-demo" in words:
                return  # services.ros2.demo's own options
            importlib.import_module(f"services.{name}").build_parser().parse_args(words[2:])
        elif name == "credentials":
            credentials = importlib.import_module("services.credentials")
            holder = argparse.ArgumentParser()
            credentials.add_parser(holder.add_subparsers(dest="c"))
            holder.parse_args(words[1:])
        else:
            from sqpmpc.cli.main import build_parser

            build_parser().parse_args(words[1:])
    elif words[:2] == ["python", "-m"]:
        assert importlib.util.find_spec(words[2]) is not None, words
        if words[2].startswith(("services.", "benchmarks.")):
            module = importlib.import_module(words[2])
            if hasattr(module, "build_parser"):
                module.build_parser().parse_args(words[3:])
    else:
        raise AssertionError(f"no check for {' '.join(words)}")


def _check_shell(words: list[str], tmp_path: Path) -> None:
    if words[0] == "sudo":
        words = words[1:]
    words = [w.removeprefix(".venv/bin/") for w in words]
    if words[0] == "make":
        targets = re.findall(r"^([a-z]+):", (ROOT / "Makefile").read_text(), re.M)
        assert all(t in targets for t in words[1:]), words
    elif words[:2] == ["docker", "compose"]:
        for j, w in enumerate(words):
            if w == "-f":
                assert (ROOT / words[j + 1]).exists() or words[j + 1].startswith("runs/") \
                    or "/" not in words[j + 1] or (tmp_path / words[j + 1]).exists(), words
    elif words[0] in ("docker", "python3", "pip", "cd", "mkdir", "id", "chmod"):
        return  # the engine, the interpreter, the shell: nothing of the project to check
    elif words[0] == "sqpmpc" and words[1] in _RUN and (
            words[1] != "run" or "--t-end" in words):
        assert sqpmpc_main(words[1:] + (["--no-plots"] if words[1] == "run" else [])) == 0, \
            words
    elif words[0] == "sqpmpc" and words[1] == "docker" and "--up" not in words:
        assert sqpmpc_main(words[1:]) == 0, words  # writes the file (--up needs an engine)
    else:
        _parse_only(words)


@pytest.mark.parametrize("page", [p for p in PAGES if any(
    k in ("sh", "bash", "") for k, _ in _blocks(p))], ids=_id)
def test_shell_blocks_parse_and_the_cheap_ones_run(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("COLUMNS", "100")
    (tmp_path / "run.toml").write_text('collision_margin = 0.05\n')
    shutil.copytree(ROOT / "tests" / "data", tmp_path / "tests" / "data")  # the maps named
    for kind, code in _blocks(page):
        if kind in ("sh", "bash", ""):  # no kind: the reports' command lines
            for words in _command_lines(code):
                _check_shell(words, tmp_path)


def test_every_code_block_has_a_known_kind():
    for page in PAGES:
        for kind, code in _blocks(page):
            assert kind in ("python", "toml", "sh", "bash", "", "text", "yaml"), (
                f"{_id(page)}: a code block of kind {kind!r} is neither run nor checked "
                f"({code[:60]!r})")



# --------------------------------------------------------------- in a headless browser
sys.path.insert(0, str(DOCS))
screenshot = importlib.import_module("screenshot")
sys.path.remove(str(DOCS))


def test_the_navigation_is_read_from_the_rendered_navbar_only():
    dom = ('<div class="navbar"><a>Home</a><a class="dropdown-toggle">Tutorial</a>'
           '<ul><li><a>Getting started</a></li></ul></div>'
           '<div class="content"><a>Reference</a></div>')
    assert screenshot.nav_of(dom) == ["Home", "Tutorial", "Getting started"]


@pytest.mark.skipif(shutil.which("chromium") is None,
                    reason="no headless browser here (Debian: apt-get install chromium)")
def test_the_site_shows_the_four_parts_in_a_headless_browser(tmp_path):
    shot = tmp_path / "home.png"
    res = subprocess.run([sys.executable, str(DOCS / "screenshot.py"), "--out", str(shot)],
                         capture_output=True, text=True, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
