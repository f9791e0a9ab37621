"""``python -m sqpmpc.kernels``: compile or load every kernel and say how long it took.

On a first start (nothing in numba's on-disk cache) compiling takes from seconds to
minutes; the kernels compiled are then reported as numba finishes them (numba's
``numba:compile`` events): a line at least every :data:`EVERY` seconds of compilation
naming the last one, so the wait is never silent. Loaded from the cache, one line at the
end.
"""

from __future__ import annotations

import sys
import time
from typing import Any

from numba.core import event

from sqpmpc.kernels.warmup import warm_up

__all__ = ["EVERY", "CompileLines", "main"]

EVERY = 2.0
"""Seconds between two progress lines while kernels compile."""


class CompileLines(event.Listener):
    """Counts the numba compilations that end (the kernels' callees included) and prints
    ``N kernels compiled (last: NAME), S s`` once :data:`EVERY` seconds have passed since
    the last line."""

    def __init__(self) -> None:
        self.started: dict[int, float] = {}
        self.count = 0
        self.t0 = self.shown = time.perf_counter()

    def on_start(self, ev: Any) -> None:
        self.started[id(ev.data.get("dispatcher"))] = time.perf_counter()

    def on_end(self, ev: Any) -> None:
        dispatcher = ev.data.get("dispatcher")
        self.started.pop(id(dispatcher), None)
        name = getattr(getattr(dispatcher, "py_func", None), "__qualname__", "kernel")
        self.count += 1
        now = time.perf_counter()
        if now - self.shown >= EVERY:
            self.shown = now
            print(f"  {self.count} kernels compiled (last: {name}), {now - self.t0:.0f} s",
                  flush=True)


def main() -> int:
    """Compile or load the kernels, with progress lines while compiling; returns 0."""
    print("sqpmpc kernels: loading from the cache, or compiling them once (a line every "
          "few seconds while compiling)", flush=True)
    lines = CompileLines()
    event.register("numba:compile", lines)
    try:
        took = warm_up()
    finally:
        event.unregister("numba:compile", lines)
    how = f"{lines.count} compiled" if lines.count else "all loaded from the cache"
    print(f"sqpmpc kernels ready in {took:.3f} s ({how})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
