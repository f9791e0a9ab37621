"""Per-sample time before and after a change, side by side in one run.

``python -m benchmarks.compare_ipopt --baseline PATH`` measures this checkout and the
checkout at ``PATH`` (for example a ``git worktree`` of the commit before the change)
with the same measure (:mod:`benchmarks.timing_probe`): each side runs in its own
subprocess with its own ``PYTHONPATH``, in ``--rounds`` rounds whose order alternates
(this, baseline; baseline, this; ...), so that both see the same machine load. The
result is the median over the rounds of each side's per-sample median, and their ratio;
the report (default ``docs/before-after.md``) lists every round with the load average.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

__all__ = ["BaselineError", "Comparison", "HERE", "PROBE", "TARGET", "compare_baseline",
           "probe", "render_baseline", "resolve_checkout"]

#: This checkout (the one the benchmarks are imported from).
HERE = Path(__file__).resolve().parents[1]
#: The measuring script, run in each checkout's environment.
PROBE = Path(__file__).resolve().with_name("timing_probe.py")
#: The target: this checkout's per-sample median at most 5 % above the baseline's.
TARGET = 1.05


class BaselineError(RuntimeError):
    """The baseline checkout cannot be measured (missing, no ``sqpmpc``, the probe failed)."""


@dataclasses.dataclass(frozen=True)
class Comparison:
    """Both sides' measures of every round.

    Attributes
    ----------
    here, baseline
        The two checkouts (paths) and their ``git describe`` (``""`` if unknown).
    rounds
        Per round: ``{"order": [...], "load": (1, 5, 15 min), "here": rows,
        "baseline": rows}``, rows as :func:`benchmarks.timing_probe.measure` returns.
    """

    here: tuple[str, str]
    baseline: tuple[str, str]
    rounds: tuple[dict[str, object], ...]

    def medians(self, side: str) -> dict[tuple[str, str], list[float]]:
        """Per ``(scenario, scheme)``: the side's per-sample medians of every round, ms."""
        out: dict[tuple[str, str], list[float]] = {}
        for r in self.rounds:
            for row in r[side]:
                out.setdefault((row["scenario"], row["scheme"]), []).append(row["median_ms"])
        return out

    def ratios(self) -> dict[tuple[str, str], float]:
        """Per ``(scenario, scheme)``: median over rounds here / median over rounds before."""
        here, base = self.medians("here"), self.medians("baseline")
        return {k: float(np.median(here[k]) / np.median(base[k])) for k in here}


def resolve_checkout(path: str | Path) -> Path:
    """The checkout root at ``path`` (a directory holding the ``sqpmpc`` package).

    Raises
    ------
    BaselineError
        Not a directory, or no ``sqpmpc/__init__.py`` in it.
    """
    root = Path(path).expanduser().resolve()
    if not root.is_dir():
        raise BaselineError(f"--baseline {path}: not a directory")
    if not (root / "sqpmpc" / "__init__.py").is_file():
        raise BaselineError(f"--baseline {path}: no sqpmpc package in it (give the root of "
                            "a checkout, e.g. a git worktree of the commit to compare with)")
    return root


def _describe(root: Path) -> str:
    try:
        done = subprocess.run(["git", "-C", str(root), "describe", "--always", "--dirty"],
                              capture_output=True, text=True, timeout=30, check=False)
    except (OSError, subprocess.SubprocessError):
        return ""
    return done.stdout.strip() if done.returncode == 0 else ""


def probe(root: Path, scenarios: Sequence[str], schemes: Sequence[str],
          iteration_scheme: str, repeats: int) -> list[dict[str, object]]:
    """Run :mod:`benchmarks.timing_probe` on the checkout ``root`` in a subprocess.

    Raises
    ------
    BaselineError
        The probe failed, or imported ``sqpmpc`` from somewhere else than ``root``.
    """
    env = dict(os.environ, PYTHONPATH=str(root))
    request = json.dumps({"scenarios": list(scenarios), "schemes": list(schemes),
                          "iteration_scheme": iteration_scheme, "repeats": repeats})
    done = subprocess.run([sys.executable, str(PROBE), request], capture_output=True,
                          text=True, env=env, cwd=str(root), check=False)
    if done.returncode != 0:
        tail = "\n".join(done.stderr.strip().splitlines()[-5:])
        raise BaselineError(f"timing probe failed on {root} (exit {done.returncode}):\n{tail}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    if not Path(result["sqpmpc"]).resolve().is_relative_to(root):
        raise BaselineError(f"timing probe on {root} imported sqpmpc from {result['sqpmpc']}")
    return result["rows"]


def compare_baseline(baseline: Path, scenarios: Sequence[str], schemes: Sequence[str],
                     iteration_scheme: str = "rti", rounds: int = 3, repeats: int = 5,
                     log: Callable[[str], None] | None = None) -> Comparison:
    """Measure this checkout and ``baseline`` in alternating rounds (see the module notes).

    Parameters
    ----------
    baseline
        Root of the checkout to compare with (:func:`resolve_checkout`).
    scenarios, schemes, iteration_scheme, repeats
        As :func:`benchmarks.timing_probe.measure`.
    rounds
        Rounds; round ``r`` runs this checkout first when ``r`` is even.
    log
        Progress callback (one line per side and round).

    Returns
    -------
    Comparison
    """
    sides = {"here": HERE, "baseline": baseline}
    out = []
    for r in range(max(1, rounds)):
        order = ["here", "baseline"] if r % 2 == 0 else ["baseline", "here"]
        entry: dict[str, object] = {"order": order, "load": os.getloadavg()}
        for side in order:
            t0 = time.perf_counter()
            entry[side] = probe(sides[side], scenarios, schemes, iteration_scheme, repeats)
            if log is not None:
                medians = ", ".join(f"{row['scenario']} {row['scheme']} "
                                    f"{row['median_ms']:.3f} ms" for row in entry[side])
                log(f"round {r + 1} {side:>8}: {medians} ({time.perf_counter() - t0:.0f} s)")
        out.append(entry)
    return Comparison((str(HERE), _describe(HERE)), (str(baseline), _describe(baseline)),
                      tuple(out))


def render_baseline(result: Comparison, command: str, machine: str,
                    iteration_scheme: str, repeats: int) -> str:
    """The Markdown report of a :class:`Comparison`."""
    here, base = result.medians("here"), result.medians("baseline")
    ratios = result.ratios()
    lines = [
        "# Per-sample time before and after",
        "",
        "<!-- written by benchmarks/compare_ipopt.py --baseline; do not edit by hand -->",
        "",
        f"Reproduce: `{command}`",
        "",
        f"- this checkout: `{result.here[0]}` {result.here[1]}",
        f"- baseline: `{result.baseline[0]}` {result.baseline[1]}",
        f"- {iteration_scheme.upper()}; per side and round a subprocess with its own "
        f"`PYTHONPATH` runs {repeats} closed loops per row (`benchmarks/timing_probe.py`); "
        "per sample the controller time summed over the robots, the smallest over the "
        "closed loops, then the median over the samples. Rounds alternate the order.",
        f"- target: this checkout's median over the rounds at most {TARGET - 1:.0%} above "
        "the baseline's.",
        "",
        "| scenario | scheme | baseline, ms (rounds) | this checkout, ms (rounds) | "
        "ratio of the medians | target |",
        "|---|---|---|---|---|---|",
    ]
    for key, ratio in ratios.items():
        scenario, scheme = key
        lines.append(
            f"| {scenario} | {scheme} | **{np.median(base[key]):.3f}** "
            f"({', '.join(f'{v:.3f}' for v in base[key])}) | **{np.median(here[key]):.3f}** "
            f"({', '.join(f'{v:.3f}' for v in here[key])}) | {ratio:.3f} | "
            f"{'met' if ratio <= TARGET else 'missed'} |")
    lines += ["", "| round | order | load average (1/5/15 min) at its start |", "|---|---|---|"]
    for i, r in enumerate(result.rounds):
        load = " / ".join(f"{v:.2f}" for v in r["load"])
        lines.append(f"| {i + 1} | {', '.join(r['order'])} | {load} |")
    same = all(row["same"] for r in result.rounds for side in ("here", "baseline")
               for row in r[side])
    lines += ["", f"Every repeat of a row gave the same closed loop: {'yes' if same else 'no'}.",
              "", machine, ""]
    return "\n".join(lines)
