"""Check the built site's navigation in a headless browser, and keep a screenshot of it.

``python docs/screenshot.py [--site DIR] [--out FILE.png] [--browser PROGRAM]`` builds the
site strictly (:mod:`build`, into ``DIR``, default a temporary folder) unless ``DIR``
already holds it, opens its home page in headless Chromium (Debian's ``chromium``), and
checks the page as the browser rendered it (its DOM after scripts ran): the navigation
bar holds the four parts, Tutorial, How-to guides, Reference and Explanation, each with
its pages. It writes the screenshot of the home page to ``FILE.png`` (default
``site-home.png``) and exits 0, or 1 naming what is missing (2: no browser).
"""

from __future__ import annotations

import argparse
import html.parser
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

__all__ = ["PARTS", "main", "nav_of"]

HERE = Path(__file__).resolve().parent
#: The navigation's parts and a page each must hold (its title in the menu).
PARTS = {"Tutorial": "Getting started", "How-to guides": "Docker for N robots",
         "Reference": "Command line", "Explanation": "What is inside"}


class _Nav(html.parser.HTMLParser):
    """The texts of the links and dropdown toggles of the page's navigation bar."""

    def __init__(self) -> None:
        super().__init__()
        self.depth = 0  # inside <nav> (or the navbar div) when > 0
        self.texts: list[str] = []
        self._in_link = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        classes = dict(attrs).get("class") or ""
        if tag == "div" and "navbar" in classes.split() or self.depth:
            self.depth += tag == "div" or tag == "nav"
        self._in_link = tag == "a" and self.depth > 0

    def handle_endtag(self, tag: str) -> None:
        if self.depth and tag in ("div", "nav"):
            self.depth -= 1
        if tag == "a":
            self._in_link = False

    def handle_data(self, data: str) -> None:
        if self._in_link and data.strip():
            self.texts.append(data.strip())


def nav_of(dom: str) -> list[str]:
    """The link texts of the navigation bar of a rendered page (mkdocs' own theme)."""
    parser = _Nav()
    parser.feed(dom)
    return parser.texts


def main(argv: list[str] | None = None) -> int:
    """Build, render, check; returns the exit status."""
    parser = argparse.ArgumentParser(prog="docs/screenshot.py",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--site", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=Path("site-home.png"))
    parser.add_argument("--browser", default="chromium")
    args = parser.parse_args(argv)
    browser = shutil.which(args.browser)
    if browser is None:
        print(f"docs/screenshot.py: no {args.browser!r} on PATH (Debian: apt-get install "
              "chromium)", file=sys.stderr)
        return 2
    site = args.site or Path(tempfile.mkdtemp(prefix="sqpmpc-site-"))
    if not (site / "index.html").exists():
        sys.path.insert(0, str(HERE))
        import build

        if build.main(["--quiet", "--site-dir", str(site), "-f",
                       str(HERE.parent / "mkdocs.yml")]) != 0:
            return 1
    page = (site / "index.html").resolve().as_uri()
    common = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
              "--window-size=1280,900"]
    dom = subprocess.run([*common, "--dump-dom", page], capture_output=True, text=True,
                         check=False).stdout
    args.out.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([*common, f"--screenshot={args.out.resolve()}", page],
                   capture_output=True, check=False)
    texts = nav_of(dom)
    missing = [f"{part} > {page_title}" for part, page_title in PARTS.items()
               if part not in texts or page_title not in texts]
    if missing or not args.out.exists():
        print(f"docs/screenshot.py: the navigation lacks {', '.join(missing) or '-'}"
              f"{'' if args.out.exists() else '; no screenshot written'} (found: {texts})",
              file=sys.stderr)
        return 1
    print(f"navigation: {', '.join(PARTS)} and their pages; screenshot {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
