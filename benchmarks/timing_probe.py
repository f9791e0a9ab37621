"""Per-sample controller time of one checkout (run as a script by :mod:`benchmarks.baseline`).

Run with ``PYTHONPATH`` naming the checkout to measure; it uses only the public API that
every version of sqpmpc has (``load_scenario``, ``SolverSettings``,
``ClosedLoopSimulation(...).run().solve_times``), so that the same measure runs on the
code before and after a change::

    PYTHONPATH=/path/to/checkout python benchmarks/timing_probe.py '{"scenarios": ["paper-s2"],
        "schemes": ["centralized", "decentralized"], "iteration_scheme": "rti", "repeats": 5}'

Measure, per scenario and scheme: ``repeats`` closed loops (deterministic); per sample the
controller time summed over the robots, the smallest over the repeats (filters out
interference, like ``timeit``), then the median and the 90th percentile over the samples,
in ms. Prints one JSON object on stdout: the measures, where ``sqpmpc`` was imported from,
and whether every repeat gave the same closed loop (bit for bit).
"""

from __future__ import annotations

import json
import sys

import numpy as np

__all__ = ["measure"]


def measure(scenarios: list[str], schemes: list[str], iteration_scheme: str,
            repeats: int) -> dict[str, object]:
    """The per-sample controller times of the checkout ``sqpmpc`` is imported from.

    Parameters
    ----------
    scenarios
        Built-in scenario names or TOML paths.
    schemes
        ``"centralized"`` and/or ``"decentralized"``.
    iteration_scheme
        ``"rti"`` or ``"sqp"``.
    repeats
        Closed loops per scenario and scheme.

    Returns
    -------
    dict
        ``{"sqpmpc": path, "rows": [{scenario, scheme, median_ms, p90_ms, samples,
        same}]}``.
    """
    import sqpmpc

    rows = []
    settings = sqpmpc.SolverSettings(iteration_scheme=iteration_scheme)
    for name in scenarios:
        scenario = sqpmpc.load_scenario(name)
        for scheme in schemes:
            times, first, same = [], None, True
            for _ in range(max(1, repeats)):
                record = sqpmpc.ClosedLoopSimulation(scenario, scheme, settings).run()
                states = np.asarray(record.states)
                if first is None:
                    first = states
                same = same and bool(np.array_equal(states, first))
                times.append(np.asarray(record.solve_times, dtype=float).sum(axis=1))
            best = np.min(np.stack(times), axis=0)
            rows.append({"scenario": name, "scheme": scheme,
                         "median_ms": float(np.median(best) * 1e3),
                         "p90_ms": float(np.percentile(best, 90) * 1e3),
                         "samples": int(best.size), "same": same})
    return {"sqpmpc": str(sqpmpc.__file__), "rows": rows}


if __name__ == "__main__":
    request = json.loads(sys.argv[1])
    print(json.dumps(measure(request["scenarios"], request["schemes"],
                             request["iteration_scheme"], int(request["repeats"]))))
