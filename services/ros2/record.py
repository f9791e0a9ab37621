"""A simulated ROS 2 fleet's log as a run folder like every other runner's.

The fleet (:mod:`services.ros2.simfleet`) logs each robot's motion exactly, as segments
``[t, x, y, psi, v, omega]`` in wall time (``poses.json``). :func:`fleet_record` samples
them at the scenario's instants ``epoch + k Ts``: the states then, and as the input of
sample ``k`` the velocities the robot was moving with at that instant (each robot's
controller runs on its own clock, so they may change within a sample). The run folder
then holds ``metrics.json``, ``trajectory.npz``, ``record.msgpack`` and
``recording.mcap`` as for ``sqpmpc run`` and ``sqpmpc launch``, and ``sqpmpc metrics``,
``sqpmpc animate`` read it. The collision check between the samples along these
straight segments is an approximation: ``check.json`` (:mod:`services.ros2.check`) holds
the exact one along the logged arcs. :func:`controller_counts` reads every controller's
final counts (``samples``, ``odometry_future``, ...) from its log, for ``metrics.json``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from sqpmpc.io.recorder import RunRecorder
from sqpmpc.problem.scenario import Scenario
from sqpmpc.sim.record import RunRecord

from .check import poses_at

__all__ = ["controller_counts", "counts_in_log", "fleet_record"]


def _velocities_at(segments: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``(T, 2)``: the segment's ``(v, omega)`` in force at each time."""
    index = np.clip(np.searchsorted(segments[:, 0], times, side="right") - 1, 0,
                    len(segments) - 1)
    return segments[index, 4:6]


def fleet_record(data: dict[str, Any], scenario: Scenario, t_end: float) -> RunRecord:
    """The :class:`RunRecord` of a fleet's ``poses.json`` content, sampled every ``Ts`` from
    its epoch up to ``t_end`` or the log's end (then ``completed`` is false).

    Parameters
    ----------
    data
        ``{"epoch", "start", "end", "robots": {id: {"diameter", "segments"}}}``.
    scenario
        The scenario the fleet ran (robot order, sample time).
    t_end
        The run's t_end, s (the demo's ``--t-end`` or the scenario's).
    """
    ts = float(scenario.sample_time)
    epoch = float(data["epoch"])
    span = min(float(data["end"]) - epoch, t_end)
    k = max(0, math.floor(span / ts + 1e-9))
    times = np.arange(k + 1) * ts
    segments = [np.asarray(data["robots"][str(int(i))]["segments"], dtype=float)
                for i in scenario.ids]
    states = np.stack([poses_at(s, epoch + times) for s in segments], axis=1)  # (K+1, n, 3)
    inputs = np.stack([_velocities_at(s, epoch + times) for s in segments], axis=1)
    steps = max(1, round(t_end / ts))
    recorder = RunRecorder(scenario.with_changes(t_end=steps * ts), "decentralized")
    for j in range(k):
        recorder.append(float(times[j]), states[j], inputs[j])
    recorder.append(float(times[k]), states[k])
    recorder.extra["solve_time_source"] = ("each controller runs on its own clock; its "
                                           "compute times are in its log, logs/robot-<id>.log")
    return recorder.record()


def counts_in_log(text: str) -> dict[str, int]:
    """A controller's final counts from its log's text (the line ``robot/<id>: 12 samples,
    0 brakes, ..., 0 invalid messages dropped`` that :class:`services.ros2.robot.Ros2Robot`
    writes when it ends); empty if the log has none (the controller did not end)."""
    counts: dict[str, int] = {}
    for line in text.splitlines():
        if " samples, " in line and "invalid messages dropped" in line:
            for part in line.split(": ", 2)[-1].split(", "):
                value, _, key = part.partition(" ")
                if value.isdigit():
                    counts[key] = counts.get(key, 0) + int(value)
    return counts


def controller_counts(logs: Path) -> dict[str, int]:
    """Every controller's final counts added up, from the ``robot-*.log`` files in ``logs``
    (a restarted controller's log too).

    Parameters
    ----------
    logs
        The run's log folder (``DIR/logs`` of :mod:`services.ros2.demo`).

    Returns
    -------
    dict
        Count name (``samples``, ``stale_odometry``, ``odometry_future``, ...) -> total.
    """
    total: dict[str, int] = {}
    for log in sorted(logs.glob("robot-*.log")):
        for key, value in counts_in_log(log.read_text(errors="replace")).items():
            total[key] = total.get(key, 0) + value
    return total
