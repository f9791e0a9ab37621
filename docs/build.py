"""Build the site strictly: any warning fails the build, with ``--quiet`` too.

``python docs/build.py [--quiet] [-f mkdocs.yml] [--site-dir DIR]`` (``make docs``,
``make test``). ``mkdocs build --strict --quiet`` exits 0 on warnings: ``--quiet``
raises mkdocs' log level to ERROR, so its own counter of warnings never sees one. This
builds through mkdocs' API with a handler of its own that counts every warning of every
logger (mkdocs, its plugins, griffe) and exits 1 naming how many there were; ``--quiet``
hides the INFO lines only, never a warning.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

__all__ = ["main"]


class _Counter(logging.Handler):
    """Counts the records of level WARNING and above, and prints them."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.count = 0

    def emit(self, record: logging.LogRecord) -> None:
        self.count += 1
        print(f"{record.levelname}: {record.getMessage()}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Build the site; returns 0, or 1 when any warning or error was logged."""
    parser = argparse.ArgumentParser(prog="docs/build.py", description=__doc__.splitlines()[0])
    parser.add_argument("-f", "--config-file", type=Path, default=Path("mkdocs.yml"))
    parser.add_argument("--site-dir", type=Path, default=None)
    parser.add_argument("--quiet", action="store_true", help="no INFO lines (warnings stay)")
    args = parser.parse_args(argv)
    from mkdocs import exceptions
    from mkdocs.commands.build import build
    from mkdocs.config import load_config

    counter = _Counter()
    root = logging.getLogger()
    root.addHandler(counter)
    root.setLevel(logging.INFO)
    if not args.quiet:
        info = logging.StreamHandler(sys.stderr)
        info.setLevel(logging.INFO)
        info.addFilter(lambda r: r.levelno < logging.WARNING)
        info.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
        root.addHandler(info)
    for name in ("mkdocs", "mkdocs_autorefs", "mkdocstrings", "griffe"):
        logging.getLogger(name).setLevel(logging.INFO)
    extra = {} if args.site_dir is None else {"site_dir": str(args.site_dir)}
    try:
        config = load_config(str(args.config_file), strict=True, **extra)
        build(config)
    except exceptions.MkDocsException as exc:
        print(f"docs/build.py: {exc}", file=sys.stderr)
        return 1
    if counter.count:
        print(f"docs/build.py: {counter.count} warning(s): the site is not built cleanly",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
