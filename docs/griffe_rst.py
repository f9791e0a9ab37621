"""A griffe extension for the API reference: the docstrings' reST roles as Markdown.

The docstrings are numpy style with reST roles (``:class:`~sqpmpc.x.Y```,
``:meth:`step```, ``:math:`x```) and ``.. math::`` blocks, which mkdocstrings
renders as Markdown. This extension rewrites them once griffe has loaded the
package: a role naming an object of sqpmpc becomes an optional cross-reference
(a link when the object is on a page of the reference, its name in code
otherwise), any other role its text in code, and a ``.. math::`` line is
dropped so that its indented formula shows as a code block.
"""

from __future__ import annotations

import re
from typing import Any

from griffe import Extension, NameResolutionError, Object

__all__ = ["RstRoles"]

_ROLE = re.compile(r":(?:py:)?(class|func|meth|attr|mod|data|exc|obj|math):`([^`]+)`")
_MATH_BLOCK = re.compile(r"^[ \t]*\.\. math::[ \t]*\n", re.M)
_LINKED = {"class", "func", "meth", "attr", "mod", "data", "exc", "obj"}


def _target(obj: Object, name: str) -> str | None:
    """The full path of ``name`` seen from ``obj``, if it is an object of sqpmpc."""
    head, _, rest = name.partition(".")
    if name.startswith("sqpmpc."):
        return name
    try:
        resolved = obj.resolve(head)
    except (NameResolutionError, ValueError, KeyError, AttributeError):
        return None
    full = f"{resolved}.{rest}" if rest else resolved
    return full if full.startswith("sqpmpc.") else None


def _convert(obj: Object, text: str) -> str:
    def role(match: re.Match[str]) -> str:
        kind, content = match.group(1), match.group(2).strip()
        if kind == "math":
            return f"`{content}`"
        short = content.startswith("~")
        name = content.lstrip("~").removesuffix("()")
        shown = name.rsplit(".", 1)[-1] if short else name
        target = _target(obj, name) if kind in _LINKED else None
        if target is None:
            return f"`{shown}`"
        return f'<autoref identifier="{target}" optional><code>{shown}</code></autoref>'

    return _ROLE.sub(role, _MATH_BLOCK.sub("", text))


class RstRoles(Extension):
    """Rewrite every docstring of the loaded package (see the module docstring)."""

    def on_object(self, *, obj: Object, **kwargs: Any) -> None:
        """Convert ``obj``'s docstring in place."""
        if obj.is_alias or obj.docstring is None:
            return
        obj.docstring.value = _convert(obj, obj.docstring.value)
