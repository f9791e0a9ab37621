"""What a run tells its user while it runs and at its end.

:class:`StatusLines`: one plain line every ``period`` seconds on a stream
(``sample 120/800 (15 %), 15 s, min clearance 0.012 m``), never a carriage
return: ``sqpmpc run`` writes them when stderr is not a terminal (a terminal
gets a progress bar), the plant service always (the launcher passes them on).
:func:`describe_solve_time`: the controller time of a run's metrics, saying
what each figure is (per robot or summed over the robots).
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

import numpy as np

from sqpmpc.io.metrics import pair_distances
from sqpmpc.problem.scenario import Scenario

__all__ = ["STATUS_PERIOD", "StatusLines", "describe_solve_time"]

STATUS_PERIOD = 10.0
"""Seconds between two status lines by default."""


class StatusLines:
    """Periodic plain status lines of a closed loop.

    Parameters
    ----------
    scenario
        The run's scenario (samples, robot distances).
    label
        Start of every line, e.g. ``"plant"``.
    period
        Seconds between two lines (``<= 0``: none).
    stream
        Where to write (default: ``sys.stderr`` at write time).
    """

    def __init__(self, scenario: Scenario, label: str, period: float = STATUS_PERIOD,
                 stream: TextIO | None = None) -> None:
        self.total = scenario.steps
        self.label = label
        self.period = float(period)
        self.stream = stream
        self.start = time.monotonic()
        self.last = self.start
        self.lines = 0
        self.pairs = scenario.pairs()
        required = scenario.required_distances()
        self.required = required[self.pairs[:, 0], self.pairs[:, 1]] if self.pairs.size else None
        self.min_clearance = np.inf

    def update(self, k: int, states: np.ndarray, extra: str = "") -> None:
        """``k`` samples done, ``states`` ``(n, 3)`` the newest; writes a line when due."""
        if self.required is not None:
            d = pair_distances(states[None, :, :2], self.pairs)[0] - self.required
            self.min_clearance = min(self.min_clearance, float(d.min()))
        now = time.monotonic()
        if self.period > 0 and now - self.last >= self.period:
            self.last = now
            self.write(k, extra)

    def write(self, k: int, extra: str = "") -> None:
        """Write one status line now."""
        clearance = ("" if not np.isfinite(self.min_clearance)
                     else f", min clearance {self.min_clearance:.3g} m")
        self.note(f"sample {k}/{self.total} ({100.0 * k / max(self.total, 1):.0f} %), "
                  f"{time.monotonic() - self.start:.0f} s{clearance}{extra}")

    def note(self, text: str) -> None:
        """Write ``label: text`` as a line now."""
        line = f"{self.label}: {text}"
        stream = self.stream or sys.stderr
        stream.write(line.replace("\r", " ") + "\n")
        stream.flush()
        self.lines += 1


def describe_solve_time(metrics: dict[str, Any]) -> str:
    """The controller time of a run's metrics, per robot and summed, in words.

    Decentralized (one controller per robot): ``controller time per sample summed over
    the 4 robots: median 3.4 ms (max 9.1 ms); per robot: median of the robots'
    medians 0.85 ms, slowest robot 0.9 ms``. Centralized: ``controller time per
    sample (one central controller): median 2.1 ms (max 5.0 ms)``.
    """
    st = metrics.get("solve_time") or {}
    controllers = int(st.get("controllers", 1) or 1)

    def ms(value: Any) -> str:
        return "n/a" if value is None else f"{value:.3g} ms"

    if controllers <= 1:
        return (f"controller time per sample (one central controller): median "
                f"{ms(st.get('median_ms'))} (max {ms(st.get('max_ms'))})")
    per_robot = [v for v in (st.get("per_robot_median_ms") or {}).values() if v is not None]
    robots = (f"; per robot: median {ms(float(np.median(per_robot)))}, slowest robot's median "
              f"{ms(max(per_robot))}" if per_robot else "")
    return (f"controller time per sample summed over the {controllers} robots: median "
            f"{ms(st.get('median_ms'))} (max {ms(st.get('max_ms'))}){robots}")
