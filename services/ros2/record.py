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
the exact one along the logged arcs.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from sqpmpc.io.recorder import RunRecorder
from sqpmpc.problem.scenario import Scenario
from sqpmpc.sim.record import RunRecord

from .check import poses_at

__all__ = ["fleet_record"]


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
