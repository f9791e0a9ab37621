"""Per-run tallies of the plant: response times and controller counters."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

__all__ = ["response_ms", "summed"]


def response_ms(responses: Mapping[int, list[float]]) -> dict[str, dict[str, float | None]]:
    """Per robot: median, 99th percentile and largest time, ms, from the states of a
    sample out to that robot's first input of it in (over the inputs that came; s in)."""
    out: dict[str, dict[str, float | None]] = {}
    for rid, times in responses.items():
        ms = np.asarray(times) * 1e3
        out[str(rid)] = {q: float(np.percentile(ms, p)) if ms.size else None
                         for q, p in (("median", 50), ("p99", 99), ("max", 100))}
    return out


def summed(counters: Iterable[Mapping[str, int]]) -> dict[str, int]:
    """Counters of several controllers added up by name."""
    total: dict[str, int] = {}
    for c in counters:
        for key, value in c.items():
            total[key] = total.get(key, 0) + int(value)
    return total
