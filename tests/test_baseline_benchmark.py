"""``compare_ipopt --baseline``: the before/after timing runs both checkouts the same way.

No timing is asserted (machines are noisy): the measure runs, in subprocesses with their
own ``PYTHONPATH``, and the report has one row per scenario and scheme.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks.baseline import (
    HERE,
    BaselineError,
    compare_baseline,
    render_baseline,
    resolve_checkout,
)
from benchmarks.compare_ipopt import main


def test_baseline_must_be_a_checkout(tmp_path: Path) -> None:
    with pytest.raises(BaselineError, match="not a directory"):
        resolve_checkout(tmp_path / "missing")
    with pytest.raises(BaselineError, match="no sqpmpc package"):
        resolve_checkout(tmp_path)
    assert main(["--baseline", str(tmp_path)]) == 2


def test_this_checkout_against_itself() -> None:
    lines: list[str] = []
    result = compare_baseline(resolve_checkout(HERE), ["head-on"], ["centralized"],
                              rounds=2, repeats=1, log=lines.append)
    assert len(result.rounds) == 2 and len(lines) == 4
    assert [r["order"] for r in result.rounds] == [["here", "baseline"], ["baseline", "here"]]
    for r in result.rounds:
        for side in ("here", "baseline"):
            (row,) = r[side]
            assert row["scenario"] == "head-on" and row["scheme"] == "centralized"
            assert row["median_ms"] > 0.0 and row["samples"] > 0 and row["same"]
    ratio = result.ratios()[("head-on", "centralized")]
    assert ratio > 0.0
    report = render_baseline(result, "cmd", "machine", "rti", 1)
    assert "| head-on | centralized |" in report and "machine" in report
