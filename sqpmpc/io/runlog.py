"""A run's incremental record: an append-only file that survives a crash of its writer.

The plant of a distributed run (:mod:`services.plant`) writes ``record.msgpack``
into its output folder as it goes: a sequence of msgpack maps (frames),
each written whole and flushed to the operating system when it is complete,
so after ``kill -9`` the file holds every sample up to the last one flushed.

- ``header`` (first): ``format`` = :data:`FORMAT`, ``version``, the scenario as
  TOML text and its digest, ``scheme``, ``ids``, ``steps``, ``sample_time``,
  ``columns`` (solve-time columns), ``x0`` (initial states), ``settings`` (the
  writer's own: mode, discretization, ...) and ``started`` (Unix time);
- ``sample`` (one per sample ``k``): ``k``, ``u`` (inputs applied on
  ``[t_k, t_k+1)``), ``x`` (states at ``t_k+1``), ``st`` (controller times),
  ``pu`` (the inputs the plant applied, with a noisy plant),
  ``failures`` (fallbacks of the sample), ``missed`` (robots braked);
- ``end`` (last, when the writer finished normally): ``completed`` and the
  writer's extra metrics.

Arrays are ``bin`` values of little-endian float64. :func:`read_record` rebuilds
a :class:`~sqpmpc.sim.record.RunRecord` from the frames that are whole and in
order (a torn last frame is ignored); ``sqpmpc metrics RUN_DIR`` writes
``metrics.json`` and ``trajectory.npz`` from it again.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import tomllib
from pathlib import Path
from typing import IO, Any

import msgpack
import numpy as np

from sqpmpc.errors import ScenarioError, SqpmpcError
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import parse_scenario
from sqpmpc.sim.record import RunRecord

__all__ = ["FORMAT", "RECORD_FILE", "RecordError", "RecordWriter", "read_record",
           "write_record"]

FORMAT = "sqpmpc-record"
"""The ``format`` field of the header frame."""
VERSION = 1
RECORD_FILE = "record.msgpack"
"""Name of the record in a run's output folder."""
MAX_FRAME = 1 << 24
"""Largest frame accepted when reading, bytes."""
_F64 = np.dtype("<f8")


class RecordError(SqpmpcError):
    """A record that cannot be read (missing, not a record, no header)."""


def _bin(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype=_F64).tobytes()


class RecordWriter:
    """Appends a run's frames to ``path`` (see the module notes).

    Parameters
    ----------
    path
        The record file (created, truncated).
    scenario
        The scenario that runs.
    scheme
        ``"centralized"`` or ``"decentralized"``.
    columns
        Solve-time columns per sample (1 or the number of robots).
    x0
        ``(n, 3)`` initial states.
    settings
        The writer's settings worth keeping (JSON-like values).
    digest
        The scenario digest the processes of the run agree on.
    """

    def __init__(self, path: str | os.PathLike[str], scenario: Scenario, scheme: str,
                 columns: int, x0: np.ndarray, settings: dict[str, Any], digest: str) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh: IO[bytes] | None = open(self.path, "wb")  # noqa: SIM115 (closed in close)
        self._write({"type": "header", "format": FORMAT, "version": VERSION,
                     "scenario": scenario.to_toml(), "digest": digest, "scheme": scheme,
                     "ids": [int(i) for i in scenario.ids], "steps": int(scenario.steps),
                     "sample_time": float(scenario.sample_time), "columns": int(columns),
                     "x0": _bin(x0), "settings": settings, "started": time.time()})

    def _write(self, frame: dict[str, Any]) -> None:
        if self._fh is None:
            return
        self._fh.write(msgpack.packb(frame, use_bin_type=True))
        self._fh.flush()  # whole frames reach the OS: a kill -9 loses nothing written

    def sample(self, k: int, inputs: np.ndarray, states: np.ndarray, solve_times: np.ndarray,
               failures: int, missed: list[int], plant_inputs: np.ndarray | None = None,
               cpu_times: np.ndarray | None = None) -> None:
        """Append sample ``k``: inputs applied at ``k``, states at ``k + 1`` (and the inputs
        the plant really applied, when they differ: input noise; the controllers' CPU
        times, when measured)."""
        frame = {"type": "sample", "k": int(k), "u": _bin(inputs), "x": _bin(states),
                 "st": _bin(solve_times), "failures": int(failures),
                 "missed": [int(i) for i in missed]}
        if plant_inputs is not None:
            frame["pu"] = _bin(plant_inputs)
        if cpu_times is not None:
            frame["ct"] = _bin(cpu_times)
        self._write(frame)

    def end(self, completed: bool, extra: dict[str, Any]) -> None:
        """Append the end frame and close the file."""
        self._write({"type": "end", "completed": bool(completed), "extra": extra})
        self.close()

    def close(self) -> None:
        """Close the file (further frames are ignored)."""
        if self._fh is not None:
            self._fh.close()
            self._fh = None


def _frames(path: Path) -> list[dict[str, Any]]:
    """The whole frames of ``path`` (a torn or foreign tail ends the list)."""
    frames: list[dict[str, Any]] = []
    with open(path, "rb") as fh:
        unpacker = msgpack.Unpacker(fh, raw=False, max_buffer_size=MAX_FRAME,
                                    strict_map_key=True)
        try:
            for frame in unpacker:
                if not isinstance(frame, dict):
                    break
                frames.append(frame)
        except Exception:  # a torn last frame (the writer was killed mid-write)
            pass
    return frames


def _array(frame: dict[str, Any], key: str, shape: tuple[int, ...]) -> np.ndarray | None:
    value = frame.get(key)
    if not isinstance(value, bytes) or len(value) != 8 * int(np.prod(shape)):
        return None
    return np.frombuffer(value, dtype=_F64).reshape(shape).copy()


def read_record(path: str | os.PathLike[str]) -> RunRecord:
    """Rebuild a run record from a record file (or a run folder holding one).

    Samples are taken in order from 0 while they are whole; the run counts as
    completed only with an ``end`` frame saying so after every sample.

    Raises
    ------
    RecordError
        No record, or no valid header.
    """
    path = Path(path)
    if path.is_dir():
        path = path / RECORD_FILE
    if not path.is_file():
        raise RecordError(f"{path}: no record ({RECORD_FILE}) to read")
    frames = _frames(path)
    if not frames or frames[0].get("type") != "header" or frames[0].get("format") != FORMAT:
        raise RecordError(f"{path}: not a {FORMAT} file (no header frame)")
    head = frames[0]
    try:
        scenario = parse_scenario(tomllib.loads(str(head["scenario"])), str(path))
        columns = int(head["columns"])
    except (KeyError, TypeError, ValueError, tomllib.TOMLDecodeError, ScenarioError) as exc:
        raise RecordError(f"{path}: unreadable header: {exc}") from None
    n, steps = scenario.n_robots, scenario.steps
    x0 = _array(head, "x0", (n, 3))
    states = [scenario.initial_states() if x0 is None else x0]
    inputs, times, failures, missed = [], [], 0, dict.fromkeys(scenario.ids.tolist(), 0)
    applied: list[np.ndarray | None] = []
    cpu: list[np.ndarray | None] = []
    end: dict[str, Any] | None = None
    for frame in frames[1:]:
        kind = frame.get("type")
        if kind == "end":
            end = frame
            break
        if kind != "sample" or frame.get("k") != len(inputs) or len(inputs) >= steps:
            break
        u, x, st = (_array(frame, "u", (n, 2)), _array(frame, "x", (n, 3)),
                    _array(frame, "st", (columns,)))
        if u is None or x is None or st is None:
            break
        inputs.append(u)
        applied.append(_array(frame, "pu", (n, 2)))
        cpu.append(_array(frame, "ct", (columns,)) if "ct" in frame else None)
        states.append(x)
        times.append(st)
        failures += int(frame.get("failures", 0))
        for rid in frame.get("missed", []):
            if rid in missed:
                missed[rid] += 1
    k = len(inputs)
    extra: dict[str, Any] = {}
    if end is not None and isinstance(end.get("extra"), dict):
        extra.update(end["extra"])
    else:
        settings = head.get("settings") if isinstance(head.get("settings"), dict) else {}
        extra.update(settings)
        extra.update({
            "distributed": True,
            "missed_deadlines": int(sum(missed.values())),
            "missed_deadlines_by_robot": {str(i): v for i, v in missed.items()},
        })
    extra["recovered_from_record"] = end is None
    completed = bool(end is not None and end.get("completed") is True and k == steps)
    plant_inputs = (np.asarray(applied).reshape(k, n, 2)
                    if k and all(a is not None for a in applied) else None)
    return RunRecord(scenario, str(head.get("scheme", "unknown")),
                     scenario.sample_time * np.arange(k + 1), np.asarray(states),
                     np.asarray(inputs).reshape(k, n, 2),
                     np.asarray(times).reshape(k, columns), failures, completed, extra,
                     plant_inputs=plant_inputs,
                     cpu_times=(np.asarray(cpu).reshape(k, columns)
                                if k and all(c is not None for c in cpu) else None))


def write_record(path: str | os.PathLike[str], record: RunRecord,
                 settings: dict[str, Any] | None = None) -> Path:
    """Write a whole run record as a record file (header, every sample, end), so that
    ``sqpmpc metrics`` reads an in-process run's folder as it reads a distributed one.

    Parameters
    ----------
    path
        The record file to write (atomically).
    record
        The run; its scenario must be a :class:`~sqpmpc.problem.scenario.Scenario` (``to_toml``).
    settings
        The writer's settings worth keeping (JSON-like values).

    Returns
    -------
    Path
        The path written.
    """
    from .atomic import atomic_path

    path = Path(path)
    scenario = record.scenario
    text = scenario.to_toml()
    extra = json.loads(json.dumps(record.extra or {}, default=str))
    with atomic_path(path) as tmp:
        writer = RecordWriter(tmp, scenario, record.scheme, record.solve_times.shape[1],
                              record.states[0], settings or {},
                              hashlib.sha256(text.encode()).hexdigest()[:16])
        try:
            for k in range(record.k):  # the run's fallbacks counted with its last sample
                writer.sample(k, record.inputs[k], record.states[k + 1],
                              record.solve_times[k],
                              int(record.solver_failures) if k == record.k - 1 else 0, [],
                              None if record.plant_inputs is None else record.plant_inputs[k],
                              None if record.cpu_times is None else record.cpu_times[k])
            writer.end(record.completed, extra)
        finally:
            writer.close()
    return path
