r"""A run as Foxglove messages: ``recording.mcap`` and the live view's channels.

:class:`FleetLog` turns one sample of a run (every robot's state, its plan,
the controllers' solve times) into messages of Foxglove's well-known schemas
(``foxglove.PoseInFrame``, ``FrameTransforms``, ``SceneUpdate``) and a few
JSON topics for the Plot panel, and logs them on the channels of a
:class:`foxglove.Context`. :func:`write_recording` sends a finished (or
partial) :class:`~sqpmpc.sim.record.RunRecord` through it into an MCAP file
(``recording.mcap`` of every run's folder, written by
:func:`sqpmpc.io.files.write_run`); ``services.viewer`` sends the live samples
of a distributed run through it to a Foxglove WebSocket server. Foxglove
(app or desktop) opens the file as it is.

Topics, all in the fixed frame ``world`` (x, y in m, z up):

==============================  =====================  ===============================
topic                           schema                 per sample
==============================  =====================  ===============================
``/robots/<id>/pose``           foxglove.PoseInFrame   exactly one message per robot:
                                                       :math:`(x, y, \psi)` at
                                                       :math:`t_k` (z = 0)
``/robots/<id>/reference``      foxglove.PoseInFrame   one per robot: :math:`r_j(t_k)`
``/robots/<id>/horizon``        foxglove.PosesInFrame  one per robot with a plan: the
                                                       :math:`N+1` predicted states of
                                                       the plan computed at :math:`k`
``/tf``                         foxglove.FrameTransforms  ``world`` -> ``robot_<id>``
``/scene``                      foxglove.SceneUpdate   one entity per robot (footprint
                                                       cylinder of its diameter,
                                                       heading arrow, plan and
                                                       reference lines, id label) and
                                                       per obstacle (``obstacle_<o>``)
``/clearance``                  JSON                   ``min`` (m), ``min_pair``,
                                                       ``pairs`` {"j-l": clearance}
                                                       (for at most 64 pairs, else
                                                       ``robots``: each robot's
                                                       nearest), ``obstacles``
``/tracking_error``             JSON                   ``robots`` {"id": m}, ``max``
``/solve_time``                 JSON                   ``total_ms``, ``budget_ms``
                                                       (:math:`T_s`), ``controllers``
==============================  =====================  ===============================

In a file, a message's log time is the sample time :math:`t_k` in
nanoseconds (the run starts at 0); the live view stamps with the wall clock.
The last sample of a run has no plan and no solve time (no input was
computed at :math:`t_K`).
"""

from __future__ import annotations

import json
import logging
import math
import os
from pathlib import Path
from typing import Any

import foxglove
import numpy as np
from foxglove import channels as fc
from foxglove import messages as fm

from sqpmpc.io.atomic import atomic_path
from sqpmpc.io.metrics import pair_distances
from sqpmpc.sim.record import RunRecord

__all__ = ["MAX_PAIRS", "POSE_TOPIC", "FleetLog", "robot_rgba", "write_recording"]

log = logging.getLogger(__name__)

POSE_TOPIC = "/robots/{id}/pose"
"""Topic of robot ``id``'s pose: exactly one message per sample."""
MAX_PAIRS = 64
"""Up to this many pairs ``/clearance`` lists every pair; above, each robot's nearest."""
FRAME = "world"
HEIGHT = 0.1  # m, height of the footprint cylinders

_NUMBER_MAP = {"type": "object", "additionalProperties": {"type": ["number", "null"]}}
_SCHEMAS: dict[str, dict[str, Any]] = {
    "/clearance": {"type": "object", "properties": {
        "t": {"type": "number"}, "min": {"type": ["number", "null"]},
        "min_pair": {"type": ["string", "null"]}, "pairs": _NUMBER_MAP, "robots": _NUMBER_MAP,
        "obstacles": _NUMBER_MAP}},
    "/tracking_error": {"type": "object", "properties": {
        "t": {"type": "number"}, "max": {"type": "number"}, "robots": _NUMBER_MAP}},
    "/solve_time": {"type": "object", "properties": {
        "t": {"type": "number"}, "total_ms": {"type": "number"},
        "budget_ms": {"type": "number"}, "controllers": _NUMBER_MAP}},
}


def robot_rgba(n: int) -> list[tuple[float, float, float, float]]:
    """One colour per robot, the same as the plots' (tab10, tab20 above 10 robots)."""
    from matplotlib import colormaps

    cmap = colormaps["tab10" if n <= 10 else "tab20"]
    return [tuple(float(c) for c in cmap(j % cmap.N)) for j in range(n)]  # type: ignore[misc]


def _color(rgba: tuple[float, ...], alpha: float | None = None) -> fm.Color:
    r, g, b, a = rgba
    return fm.Color(r=r, g=g, b=b, a=a if alpha is None else alpha)


def _yaw(psi: float) -> fm.Quaternion:
    return fm.Quaternion(x=0.0, y=0.0, z=math.sin(0.5 * psi), w=math.cos(0.5 * psi))


def _pose(x: float, y: float, psi: float = 0.0, z: float = 0.0) -> fm.Pose:
    return fm.Pose(position=fm.Vector3(x=float(x), y=float(y), z=z), orientation=_yaw(float(psi)))


def _stamp(ns: int) -> fm.Timestamp:
    return fm.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


class FleetLog:
    """The channels of a run's view in ``context`` and the messages of one sample.

    Parameters
    ----------
    scenario
        The scenario that runs (``ids``, ``diameters()``, ``horizon``,
        ``sample_time``, ``reference_positions(t)``, ``pairs()``,
        ``required_distances()``, ``obstacles``).
    context
        The Foxglove context whose sinks (an MCAP writer, a WebSocket server)
        receive the messages.
    """

    def __init__(self, scenario: Any, context: foxglove.Context) -> None:
        self.scenario = scenario
        self.ids = [int(i) for i in np.asarray(scenario.ids).reshape(-1)]
        self.diameters = np.asarray(scenario.diameters(), dtype=float)
        self.colors = robot_rgba(len(self.ids))
        self.obstacles = tuple(getattr(scenario, "obstacles", ()) or ())
        self.polygons = tuple(getattr(scenario, "polygons", ()) or ())
        pairs = np.asarray(scenario.pairs(), dtype=np.int64).reshape(-1, 2)
        self.pairs = pairs
        self.required = np.asarray(scenario.required_distances(), dtype=float)[
            pairs[:, 0], pairs[:, 1]]
        self.pair_names = [f"{self.ids[a]}-{self.ids[b]}" for a, b in pairs]
        self.pose = [fc.PoseInFrameChannel(POSE_TOPIC.format(id=i), context=context)
                     for i in self.ids]
        self.reference = [fc.PoseInFrameChannel(f"/robots/{i}/reference", context=context)
                          for i in self.ids]
        self.horizon = [fc.PosesInFrameChannel(f"/robots/{i}/horizon", context=context)
                        for i in self.ids]
        self.tf = fc.FrameTransformsChannel("/tf", context=context)
        self.scene = fc.SceneUpdateChannel("/scene", context=context)
        self.json = {
            topic: foxglove.Channel(topic, message_encoding="json", context=context,
                                    schema=foxglove.Schema(
                                        name=f"sqpmpc.{topic.strip('/')}", encoding="jsonschema",
                                        data=json.dumps(schema).encode()))
            for topic, schema in _SCHEMAS.items()}
        self.samples = 0

    # ------------------------------------------------------------------ parts
    def _robot_entity(self, j: int, stamp: fm.Timestamp, state: np.ndarray,
                      plan: np.ndarray | None, ref_line: np.ndarray) -> fm.SceneEntity:
        x, y, psi = (float(v) for v in state)
        d, rgba = float(self.diameters[j]), self.colors[j]
        lines = [fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=0.02,
                                  points=[fm.Point3(x=float(p[0]), y=float(p[1]), z=0.01)
                                          for p in ref_line],
                                  color=_color(rgba, 0.35))]
        if plan is not None and np.isfinite(plan).all():
            lines.append(fm.LinePrimitive(
                type=fm.LinePrimitiveLineType.LineStrip, thickness=0.03,
                points=[fm.Point3(x=float(p[0]), y=float(p[1]), z=0.5 * HEIGHT) for p in plan],
                color=_color(rgba, 0.9)))
        return fm.SceneEntity(
            timestamp=stamp, frame_id=FRAME, id=f"robot_{self.ids[j]}",
            cylinders=[fm.CylinderPrimitive(
                pose=_pose(x, y, 0.0, 0.5 * HEIGHT), size=fm.Vector3(x=d, y=d, z=HEIGHT),
                bottom_scale=1.0, top_scale=1.0, color=_color(rgba, 0.55))],
            arrows=[fm.ArrowPrimitive(pose=_pose(x, y, psi, HEIGHT), shaft_length=0.45 * d,
                                      shaft_diameter=0.08 * d, head_length=0.25 * d,
                                      head_diameter=0.22 * d, color=_color(rgba, 1.0))],
            spheres=[fm.SpherePrimitive(pose=_pose(*ref_line[0]),
                                        size=fm.Vector3(x=0.08, y=0.08, z=0.08),
                                        color=_color(rgba, 0.8))],
            texts=[fm.TextPrimitive(pose=_pose(x, y, 0.0, 2.0 * HEIGHT), billboard=True,
                                    font_size=14.0, scale_invariant=True,
                                    color=fm.Color(r=0.1, g=0.1, b=0.1, a=1.0),
                                    text=str(self.ids[j]))],
            lines=lines)

    def _obstacle_entities(self, stamp: fm.Timestamp, t: float) -> list[fm.SceneEntity]:
        out = []
        for o, obstacle in enumerate(self.obstacles):
            cx, cy = (float(v) for v in obstacle.position_at(t))
            d = float(obstacle.diameter)
            out.append(fm.SceneEntity(
                timestamp=stamp, frame_id=FRAME, id=f"obstacle_{o}",
                cylinders=[fm.CylinderPrimitive(
                    pose=_pose(cx, cy, 0.0, HEIGHT), size=fm.Vector3(x=d, y=d, z=2 * HEIGHT),
                    bottom_scale=1.0, top_scale=1.0,
                    color=fm.Color(r=0.35, g=0.35, b=0.35, a=0.8))]))
        grey = fm.Color(r=0.35, g=0.35, b=0.35, a=0.8)
        for o, polygon in enumerate(self.polygons):
            # a triangle fan per convex piece (the floor plan) and the outline on top
            tris = [fm.Point3(x=float(v[0]), y=float(v[1]), z=0.0)
                    for piece in polygon.pieces for i in range(1, len(piece) - 1)
                    for v in (piece[0], piece[i], piece[i + 1])]
            ring = [*polygon.points, polygon.points[0]]
            out.append(fm.SceneEntity(
                timestamp=stamp, frame_id=FRAME, id=f"polygon_{o}",
                triangles=[fm.TriangleListPrimitive(pose=_pose(0.0, 0.0, 0.0, 0.0),
                                                    points=tris, color=grey)],
                lines=[fm.LinePrimitive(
                    type=fm.LinePrimitiveLineType.LineStrip, thickness=0.03,
                    points=[fm.Point3(x=float(x), y=float(y), z=HEIGHT) for x, y in ring],
                    color=grey)]))
        return out

    def _clearance(self, t: float, pos: np.ndarray) -> dict[str, Any]:
        out: dict[str, Any] = {"t": t, "min": None, "min_pair": None}
        if self.pairs.shape[0]:
            c = pair_distances(pos[None], self.pairs)[0] - self.required
            i = int(np.argmin(c))
            out["min"], out["min_pair"] = _finite(c[i]), self.pair_names[i]
            if self.pairs.shape[0] <= MAX_PAIRS:
                out["pairs"] = {name: _finite(v) for name, v in zip(self.pair_names, c,
                                                                    strict=True)}
            else:
                nearest = np.full(len(self.ids), np.inf)
                np.minimum.at(nearest, self.pairs[:, 0], c)
                np.minimum.at(nearest, self.pairs[:, 1], c)
                out["robots"] = {str(i): _finite(v) for i, v in zip(self.ids, nearest,
                                                                    strict=True)}
        if self.obstacles:
            centres = np.stack([o.position_at(t) for o in self.obstacles])  # (O, 2)
            dod = np.array([o.diameter for o in self.obstacles])
            gap = (np.linalg.norm(pos[:, None, :] - centres[None], axis=-1)
                   - 0.5 * (self.diameters[:, None] + dod[None]))
            out["obstacles"] = {str(i): _finite(v) for i, v in zip(self.ids, gap.min(axis=1),
                                                                   strict=True)}
            if out["min"] is None or gap.min() < out["min"]:
                o = int(np.argmin(gap.min(axis=0)))
                out["min"], out["min_pair"] = _finite(gap.min()), f"obstacle {o}"
        if self.polygons:
            radius = 0.5 * self.diameters
            gap = np.stack([p.signed_distance(pos) - radius for p in self.polygons], axis=1)
            near = gap.min(axis=1)
            if "obstacles" in out:
                near = np.minimum(near, [out["obstacles"][str(i)] for i in self.ids])
            out["obstacles"] = {str(i): _finite(v) for i, v in zip(self.ids, near,
                                                                   strict=True)}
            if out["min"] is None or gap.min() < out["min"]:
                o = int(np.argmin(gap.min(axis=0)))
                out["min"], out["min_pair"] = _finite(gap.min()), f"polygon {o}"
        return out

    # ------------------------------------------------------------------- log
    def log_sample(self, t: float, states: np.ndarray, plans: np.ndarray | None = None,
                   solve_times: np.ndarray | None = None, log_time: int | None = None) -> None:
        """Log sample ``t_k`` on every channel.

        Parameters
        ----------
        t
            Sample time :math:`t_k`, s.
        states
            ``(n, 3)`` states of every robot (scenario order).
        plans
            ``(n, N+1, 3)`` plans computed at :math:`t_k` (a robot's rows NaN:
            none); ``None``: no plan at all.
        solve_times
            Controller computation times of this sample, s (one per
            controller); ``None``: none.
        log_time
            Log time and stamp of every message, ns; default :math:`t_k`.
        """
        ns = int(round(t * 1e9)) if log_time is None else int(log_time)
        stamp = _stamp(ns)
        sc = self.scenario
        N, ts = int(sc.horizon), float(sc.sample_time)
        ref_t = t + ts * np.arange(N + 1)
        ref = np.asarray(sc.reference_positions(ref_t), dtype=float)  # (N+1, n, 2)
        transforms = []
        entities = []
        for j, rid in enumerate(self.ids):
            x, y, psi = (float(v) for v in states[j])
            self.pose[j].log(fm.PoseInFrame(timestamp=stamp, frame_id=FRAME,
                                            pose=_pose(x, y, psi)), log_time=ns)
            step = ref[1, j] - ref[0, j]
            heading = math.atan2(step[1], step[0]) if np.hypot(*step) > 1e-12 else 0.0
            self.reference[j].log(fm.PoseInFrame(timestamp=stamp, frame_id=FRAME,
                                                 pose=_pose(*ref[0, j], heading)), log_time=ns)
            plan = None if plans is None else plans[j]
            if plan is not None and np.isfinite(plan).all():
                self.horizon[j].log(fm.PosesInFrame(
                    timestamp=stamp, frame_id=FRAME,
                    poses=[_pose(*p) for p in plan]), log_time=ns)
            transforms.append(fm.FrameTransform(
                timestamp=stamp, parent_frame_id=FRAME, child_frame_id=f"robot_{rid}",
                translation=fm.Vector3(x=x, y=y, z=0.0), rotation=_yaw(psi)))
            entities.append(self._robot_entity(j, stamp, states[j], plan, ref[:, j]))
        entities.extend(self._obstacle_entities(stamp, t))
        self.tf.log(fm.FrameTransforms(transforms=transforms), log_time=ns)
        self.scene.log(fm.SceneUpdate(entities=entities), log_time=ns)
        pos = np.asarray(states, dtype=float)[:, :2]
        self.json["/clearance"].log(self._clearance(t, pos), log_time=ns)
        err = np.linalg.norm(pos - ref[0], axis=-1)
        self.json["/tracking_error"].log(
            {"t": t, "max": float(err.max()),
             "robots": {str(i): float(e) for i, e in zip(self.ids, err, strict=True)}},
            log_time=ns)
        if solve_times is not None:
            st = np.asarray(solve_times, dtype=float).reshape(-1) * 1e3
            names = [str(i) for i in self.ids] if st.size == len(self.ids) else ["central"]
            self.json["/solve_time"].log(
                {"t": t, "total_ms": float(st.sum()), "budget_ms": ts * 1e3,
                 "controllers": {k: float(v) for k, v in zip(names, st, strict=False)}},
                log_time=ns)
        self.samples += 1


def write_recording(path: str | os.PathLike[str], record: RunRecord) -> Path:
    """Write ``record`` as an MCAP file of the topics of :class:`FleetLog`.

    Samples :math:`k = 0..K` (as far as the record goes), log time
    :math:`t_k`. The plans come from :attr:`RunRecord.horizons` (none when
    it is ``None``). The file is written to a temporary name and renamed, so
    ``path`` is either complete or absent.

    Returns
    -------
    Path
        The path written.
    """
    path = Path(path)
    with atomic_path(path) as tmp:
        context = foxglove.Context()
        writer = foxglove.open_mcap(str(tmp), allow_overwrite=True, context=context)
        try:
            fleet = FleetLog(record.scenario, context)
            horizons = record.horizons
            for k in range(record.k + 1):
                last = k == record.k
                fleet.log_sample(float(record.t[k]), record.states[k],
                                 None if horizons is None or last else horizons[k],
                                 None if last else record.solve_times[k])
        finally:
            writer.close()
    log.debug("wrote %s (%d samples)", path, record.k + 1)
    return path
