"""Collect a run from your own loop, and the output folder of any run.

:class:`RunRecorder` is what a loop you wrote (a real robot, another
simulator, your own controller) hands its samples to, one call per sample;
:meth:`RunRecorder.write` then writes the same folder as ``sqpmpc run``:
``metrics.json`` (contract section 3, arrivals included), ``trajectory.npz``,
``record.msgpack`` (read again by ``sqpmpc metrics``), ``recording.mcap`` (for
Foxglove) and the PNG plots::

    rec = sqpmpc.RunRecorder(scenario, "centralized")
    x = scenario.initial_states()
    for k in range(scenario.steps):
        t = k * scenario.sample_time
        out = controller.step(t, x)
        rec.append(t, x, out)             # the states at t and what was applied from t
        x, _ = plant.step(x, out.inputs)  # or the measured poses
    rec.append(scenario.steps * scenario.sample_time, x)  # the final states
    metrics = rec.write("runs/mine")

:func:`prepare_output` is the check every run applies to its output folder
before it starts: a file or a non-empty folder is refused unless
``overwrite`` (then the previous run's own files are removed, nothing else).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.io.files import write_run
from sqpmpc.sim.record import RunRecord

__all__ = ["RUN_FILES", "RunRecorder", "owner_hint", "prepare_output"]

RUN_FILES = ("metrics.json", "trajectory.npz", "record.msgpack", "recording.mcap",
             "animation.gif", "animation.mp4", "*.png")
"""The files a run writes into its folder (glob patterns), removed by ``overwrite``."""


def owner_hint(out: str | os.PathLike[str]) -> str:
    """A hint for an output folder this process may not write: ``""`` when it may (or
    when the folder's nearest existing parent is writable)."""
    path = Path(out).absolute()
    parent = next((p for p in (path, *path.parents) if p.exists()), None)
    if parent is None or os.access(parent, os.W_OK):
        return ""
    return (f" ({parent} is not writable by uid {os.getuid()}: create it as this user, "
            f"or 'chmod a+w {parent}')")


def prepare_output(out: str | os.PathLike[str], overwrite: bool = False) -> Path:
    """Check (and create) a run's output folder before the run starts.

    Parameters
    ----------
    out
        The folder.
    overwrite
        Whether a folder holding files may be used: the files of a previous run in it
        (:data:`RUN_FILES`) are then removed, so that no old plot stays beside new
        metrics; other files are left alone.

    Returns
    -------
    Path
        The folder, existing and free of a previous run's files.

    Raises
    ------
    ProblemError
        ``out`` is a file, or a non-empty folder without ``overwrite``, or cannot be
        created.
    """
    path = Path(out)
    if path.exists() and not path.is_dir():
        raise ProblemError(f"{path} is a file, not a folder: give a folder for the run's "
                           "outputs")
    if path.is_dir() and any(path.iterdir()):
        if not overwrite:
            raise ProblemError(f"{path} is not empty (a previous run?): give a new folder, or "
                               "--overwrite to replace the run in it")
        for pattern in RUN_FILES:
            for old in path.glob(pattern):
                if old.is_file():
                    old.unlink()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ProblemError(f"cannot create {path}: {exc.strerror or exc}") from None
    return path


def _outputs(inputs: Any) -> list[Any] | None:
    """The controller outputs in ``inputs`` (one, or a list), or ``None`` for an array."""
    outputs = inputs if isinstance(inputs, list | tuple) else [inputs]
    return outputs if outputs and all(hasattr(o, "inputs") for o in outputs) else None


class RunRecorder:
    """Collects a closed loop sample by sample and writes it like ``sqpmpc run``.

    Parameters
    ----------
    scenario
        The scenario the loop runs (its robots, references, bounds and timing are
        what the metrics are computed against).
    scheme
        A label for the run: ``"centralized"``, ``"decentralized"`` or your own.

    Notes
    -----
    Call :meth:`append` once per sample ``k`` with the states at :math:`t_k` and the
    inputs applied on :math:`[t_k, t_{k+1})`, then once more with the final states
    alone. An input appended with no state after it is not part of the record.
    """

    def __init__(self, scenario: Any, scheme: str = "own loop") -> None:
        self.scenario = scenario
        self.scheme = str(scheme)
        self.n = int(scenario.n_robots)
        self.t: list[float] = []
        self.states: list[np.ndarray] = []
        self.inputs: list[np.ndarray] = []
        self.plant_inputs: list[np.ndarray | None] = []
        self.solve_times: list[np.ndarray] = []
        self.cpu_times: list[np.ndarray | None] = []
        self.horizons: list[np.ndarray | None] = []
        self.solver_failures = 0
        self.extra: dict[str, Any] = {}

    @staticmethod
    def inputs_of(outputs: Any) -> np.ndarray:
        """The ``(n, 2)`` inputs of a controller output or a list of them (one per robot,
        in the scenario's order), to give to the plant."""
        found = _outputs(outputs)
        if found is None:
            return np.asarray(outputs, dtype=float)
        return np.concatenate([np.asarray(o.inputs, dtype=float).reshape(-1, 2)
                               for o in found])

    def append(self, t: float, states: np.ndarray, inputs: Any = None,
               solve_time: float | Sequence[float] | None = None,
               plant_inputs: np.ndarray | None = None, fallbacks: int = 0,
               cpu_time: float | Sequence[float] | None = None) -> None:
        """Add sample ``k``: the time, the states then and what was applied from then.

        Parameters
        ----------
        t
            :math:`t_k`, s, larger than the previous sample's.
        states
            ``(n, 3)`` states :math:`(x, y, \\psi)` at ``t`` (measured or simulated), in
            the scenario's robot order.
        inputs
            ``(n, 2)`` inputs :math:`(v, \\omega)` applied on :math:`[t_k, t_{k+1})`; or the
            :class:`~sqpmpc.ControlOutput` of a centralized controller, or the list of the
            decentralized controllers' outputs (their inputs, compute times, CPU
            times and fallbacks are taken); ``None`` for the final states.
        solve_time
            Controller time of the sample, s: one number, or one per robot
            (decentralized). Default: the outputs' times, else 0.
        plant_inputs
            ``(n, 2)`` the inputs the robots really applied, when they differ.
        fallbacks
            Fallback inputs applied at this sample (added to the outputs' fallbacks).
        cpu_time
            The controllers' CPU time of the sample, s, shaped as ``solve_time``.
            Default: the outputs' CPU times when ``solve_time`` is not given.

        Raises
        ------
        ProblemError
            A shape that does not fit the scenario, a non-finite value, a time not after
            the previous one, or a sample after the final states.
        """
        k = len(self.t)
        if k and len(self.inputs) < k:
            raise ProblemError(f"sample {k}: the final states were already appended (an "
                               "append without inputs ends the run)")
        t = float(t)
        if not np.isfinite(t) or (k and t <= self.t[-1]):
            raise ProblemError(f"sample {k}: t = {t!r} must be finite and after the previous "
                               f"sample's t = {self.t[-1] if k else None!r}")
        x = np.asarray(states, dtype=float)
        if x.shape != (self.n, 3) or not np.all(np.isfinite(x)):
            raise ProblemError(f"sample {k}: states must be finite with shape ({self.n}, 3), "
                               f"got {x.shape}")
        self.t.append(t)
        self.states.append(x.copy())
        if inputs is None:
            return
        outputs = _outputs(inputs)
        u = self.inputs_of(inputs)
        times = failed = cpu = None
        horizon = None
        if outputs is not None:
            times = [float(o.compute_time) for o in outputs]
            cpu = np.array([float(getattr(o, "cpu_time", np.nan)) for o in outputs])
            failed = sum(o.fallback is not None for o in outputs)
            try:
                horizon = np.concatenate([np.asarray(o.predicted_states, dtype=float)
                                          for o in outputs])
            except (AttributeError, ValueError):
                horizon = None
        if u.shape != (self.n, 2) or not np.all(np.isfinite(u)):
            self.t.pop()
            self.states.pop()
            raise ProblemError(f"sample {k}: inputs must be finite with shape ({self.n}, 2), "
                               f"got {u.shape}")
        st = np.atleast_1d(np.asarray(solve_time if solve_time is not None else
                                      (times if times is not None else 0.0), dtype=float))
        if st.size not in (1, self.n):
            self.t.pop()
            self.states.pop()
            raise ProblemError(f"sample {k}: solve_time must be one number or one per robot "
                               f"({self.n}), got {st.size}")
        if self.solve_times and st.shape != self.solve_times[0].shape:
            self.t.pop()
            self.states.pop()
            raise ProblemError(f"sample {k}: solve_time has {st.size} value(s), the first "
                               f"sample had {self.solve_times[0].size}")
        self.inputs.append(u.copy())
        self.solve_times.append(st)
        # the given CPU times, or the outputs' when they are the sample's times; all measured
        if cpu_time is not None:
            cpu = np.atleast_1d(np.asarray(cpu_time, dtype=float))
        elif solve_time is not None:
            cpu = None
        self.cpu_times.append(cpu if cpu is not None and cpu.shape == st.shape
                              and np.all(np.isfinite(cpu)) else None)
        self.plant_inputs.append(None if plant_inputs is None
                                 else np.asarray(plant_inputs, dtype=float).reshape(self.n, 2))
        self.horizons.append(horizon)
        self.solver_failures += int(failed or 0) + int(fallbacks)

    def record(self) -> RunRecord:
        """The run collected so far (an input without a state after it is left out).

        Raises
        ------
        ProblemError
            Nothing appended yet.
        """
        if not self.t:
            raise ProblemError("nothing recorded: append at least the initial states")
        k = len(self.t) - 1
        columns = self.solve_times[0].size if self.solve_times else 1
        applied = self.plant_inputs[:k]
        plans = self.horizons[:k]
        shape = (self.n, int(self.scenario.horizon) + 1, 3)
        steps = int(self.scenario.steps)
        extra = dict(self.extra)
        # the machine's load when the record is taken (wall times grow with it)
        extra.setdefault("load_average", [float(v) for v in os.getloadavg()])
        extra.setdefault("cpus", os.cpu_count())
        return RunRecord(
            self.scenario, self.scheme, np.asarray(self.t), np.asarray(self.states),
            np.asarray(self.inputs[:k]).reshape(k, self.n, 2),
            np.asarray(self.solve_times[:k]).reshape(k, columns), self.solver_failures,
            completed=k >= steps, extra=extra,
            plant_inputs=(np.asarray(applied) if k and all(a is not None for a in applied)
                          else None),
            horizons=(np.asarray(plans) if k and all(h is not None and h.shape == shape
                                                     for h in plans) else None),
            cpu_times=(np.asarray(self.cpu_times[:k]).reshape(k, columns)
                       if k and all(c is not None for c in self.cpu_times[:k]) else None))

    def write(self, out: str | os.PathLike[str], plots: bool = True, recording: bool = True,
              overwrite: bool = False) -> dict[str, Any]:
        """Write the run into the folder ``out`` (see the module notes); returns the metrics.

        Raises
        ------
        ProblemError
            ``out`` is a file or a non-empty folder without ``overwrite``
            (:func:`prepare_output`), or nothing was recorded.
        """
        record = self.record()
        return write_run(prepare_output(out, overwrite), record, plots=plots,
                         recording=recording)
