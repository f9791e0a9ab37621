"""Writing and reading a run's files: ``trajectory.npz``, ``metrics.json`` and the whole run
folder (:func:`write_run`), every file written atomically.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from sqpmpc.io.atomic import atomic_path
from sqpmpc.io.metrics import _jsonable, compute_metrics
from sqpmpc.sim.record import RunRecord

__all__ = ["load_trajectory", "write_metrics", "write_plots", "write_run", "write_trajectory"]


def _atomic_write(path: Path, write: Callable[[Any], None], mode: str) -> None:
    """Write through ``write(fileobj)`` to a temporary file, then rename onto ``path``."""
    with atomic_path(path) as tmp, open(tmp, mode) as fh:
        write(fh)


def write_trajectory(path: str | os.PathLike[str], record: RunRecord) -> Path:
    """Write the trajectory as an ``.npz`` archive (no pickled objects).

    Arrays: ``t`` ``(k+1,)``, ``states`` ``(k+1, n, 3)``, ``inputs``
    ``(k, n, 2)``, ``ids`` ``(n,)`` (int64), ``solve_times`` ``(k, c)``
    seconds (wall time) and ``references`` ``(k+1, n, 2)``; when recorded, also
    ``cpu_times`` ``(k, c)`` seconds (the controllers' thread CPU time),
    ``plant_inputs`` ``(k, n, 2)`` and ``horizons`` ``(k, n, N+1, 3)``
    (float32, the plans of :attr:`RunRecord.horizons`); ``diameters`` ``(n,)``;
    with polygon obstacles ``polygon_points`` ``(V, 2)`` and ``polygon_sizes`` ``(P,)``,
    with obstacles ``obstacle_diameters`` ``(O,)`` and ``obstacle_positions``
    ``(k+1, O, 2)``. The file is written atomically.

    Returns
    -------
    Path
        The path written.
    """
    path = Path(path)
    arrays = {
        "t": record.t,
        "states": record.states,
        "inputs": record.inputs,
        "ids": record.ids,
        "solve_times": record.solve_times,
        "references": record.references(),
    }
    if record.cpu_times is not None:
        arrays["cpu_times"] = record.cpu_times
    if record.plant_inputs is not None:
        arrays["plant_inputs"] = record.plant_inputs
    if record.horizons is not None:
        arrays["horizons"] = record.horizons.astype(np.float32)
    diameters = getattr(record.scenario, "diameters", None)
    if callable(diameters):
        arrays["diameters"] = np.asarray(diameters(), dtype=float)
    obstacles = tuple(getattr(record.scenario, "obstacles", ()) or ())
    if obstacles:
        arrays["obstacle_diameters"] = np.array([o.diameter for o in obstacles])
        arrays["obstacle_positions"] = np.stack([o.position_at(record.t) for o in obstacles],
                                                axis=1)
    polygons = tuple(getattr(record.scenario, "polygons", ()) or ())
    if polygons:  # every polygon's vertices, concatenated, and how many each has
        arrays["polygon_points"] = np.concatenate([np.asarray(p.points) for p in polygons])
        arrays["polygon_sizes"] = np.array([len(p.points) for p in polygons], dtype=np.int64)
    _atomic_write(path, lambda fh: np.savez(fh, **arrays), "wb")
    return path


def load_trajectory(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Load a trajectory written by :func:`write_trajectory` (``allow_pickle=False``)."""
    with np.load(Path(path), allow_pickle=False) as data:
        return {name: data[name] for name in data.files}


def write_metrics(path: str | os.PathLike[str], metrics: dict[str, Any]) -> Path:
    """Write ``metrics`` as indented JSON, atomically (temporary file + ``os.replace``).

    Raises
    ------
    ValueError
        If the dict holds a non-finite float (strict JSON has none).
    """
    path = Path(path)
    text = json.dumps(_jsonable(metrics), indent=2, allow_nan=False) + "\n"
    _atomic_write(path, lambda fh: fh.write(text), "w")
    return path


def write_run(
    out_dir: str | os.PathLike[str],
    record: RunRecord,
    plots: bool = True,
    plotter: Callable[[RunRecord, Path], Any] | None = None,
    recording: bool = True,
) -> dict[str, Any]:
    """Write a run's outputs into ``out_dir`` and return its metrics.

    ``trajectory.npz`` and ``metrics.json`` are written first, then ``record.msgpack``
    (:func:`sqpmpc.io.runlog.write_record`, read by ``sqpmpc metrics``) unless the
    folder has one (a distributed plant writes its own as it runs); then, when
    ``recording`` is true, ``recording.mcap`` (:func:`sqpmpc.io.recording.write_recording`,
    for Foxglove); then, when ``plots`` is true, the PNG figures via ``plotter``
    (default :func:`sqpmpc.io.plots.plot_run`). An exception while recording or
    plotting propagates, but only after the trajectory and metrics are on disk.

    Parameters
    ----------
    out_dir
        Output directory, created if missing.
    record
        The (possibly partial) run record.
    plots
        Whether to draw the figures.
    plotter
        ``plotter(record, out_dir)`` drawing the figures; for tests and
        alternative renderers.
    recording
        Whether to write ``recording.mcap``.

    Returns
    -------
    dict
        The metrics, as written to ``metrics.json``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_trajectory(out / "trajectory.npz", record)
    metrics = compute_metrics(record)
    write_metrics(out / "metrics.json", metrics)
    if not (out / "record.msgpack").exists() and hasattr(record.scenario, "to_toml"):
        from sqpmpc.io.runlog import write_record  # a distributed plant writes its own

        write_record(out / "record.msgpack", record)
    if recording:
        from sqpmpc.io.recording import write_recording

        write_recording(out / "recording.mcap", record)
    if plots:
        if plotter is None:
            from sqpmpc.io.plots import plot_run

            plotter = plot_run
        plotter(record, out)
    return metrics


def write_plots(out_dir: str | os.PathLike[str], record: RunRecord, quiet: bool = False,
                plotter: Callable[[RunRecord, Path], Any] | None = None) -> None:
    """Draw a run's PNG figures into ``out_dir`` after its summary was printed.

    Unless ``quiet``, a line per figure as it is written (its name, how many, the time so
    far), so the wait after the summary is not silent.

    Parameters
    ----------
    out_dir
        The run folder.
    record
        The run record.
    quiet
        No progress lines.
    plotter
        ``plotter(record, out_dir)``; default :func:`sqpmpc.io.plots.plot_run` (the only
        one whose figures are reported one by one).
    """
    import time

    start = time.perf_counter()
    if plotter is not None:
        plotter(record, Path(out_dir))
        return
    from sqpmpc.io.plots import plot_run

    def line(path: Path, done: int, total: int) -> None:
        if not quiet:
            print(f"plots: {path.name} ({done}/{total}, {time.perf_counter() - start:.1f} s)",
                  flush=True)

    plot_run(record, Path(out_dir), progress=line)
