"""Reference trajectories :math:`r(t) = (x_r(t), y_r(t))` of the robots.

Three kinds, matching the scenario file's ``reference`` inline table:

- :class:`HarmonicReference` (``type = "harmonic"``), the seed paper's Table 1:

  .. math::

     x_r(t) = c_x + s_x \\sin(\\omega t) + k_x \\cos(\\omega t), \\qquad
     y_r(t) = c_y + s_y \\sin(\\omega t) + k_y \\cos(\\omega t).

- :class:`PointReference` (``type = "point"``): a fixed goal :math:`r(t) = p`.
- :class:`WaypointReference` (``type = "waypoints"``): piecewise linear in time
  through points :math:`p_i` at times :math:`t_i`, held at :math:`p_0` before
  :math:`t_0` and at the last point after the last time.

Every reference is vectorized: ``position(t)`` and ``velocity(t)`` take a float
or an array of any shape and return an array of shape ``np.shape(t) + (2,)``.
Constructors raise :class:`ValueError` for bad values; :func:`reference_from_dict`
turns the TOML form into a reference and raises
:class:`~sqpmpc.errors.ScenarioError` naming the key.
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.kernels.references import harmonic_positions

__all__ = [
    "HarmonicReference",
    "PointReference",
    "Reference",
    "ReferenceSet",
    "WaypointReference",
    "reference_from_dict",
]


# ---------------------------------------------------------------------------
# validation helpers (shared with sqpmpc.problem.scenario)
# ---------------------------------------------------------------------------


class _FieldError(ProblemError, ValueError):
    """A bad value for one field; ``key`` is relative to the object being built.

    A :class:`~sqpmpc.errors.ProblemError` when a reference or scenario part is
    built in code; the scenario loader turns it into a
    :class:`~sqpmpc.errors.ScenarioError` naming the file and the key.
    """

    def __init__(self, key: str, detail: str) -> None:
        self.key = key
        self.detail = detail
        super().__init__(f"{key}: {detail}")


def _describe(value: Any) -> str:
    """Short human description of a (TOML) value for error messages."""
    if isinstance(value, bool | np.bool_):
        return f"{str(bool(value)).lower()} (a boolean)"
    if isinstance(value, str):
        text = value if len(value) <= 40 else value[:37] + "..."
        return f"{text!r} (a string)"
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, list | tuple | np.ndarray):
        text = repr(list(value) if not isinstance(value, list) else value)
        if len(text) > 60:
            text = text[:57] + "..."
        return f"{text} (an array of {len(value)})"
    if isinstance(value, numbers.Integral):
        return f"{int(value)} (an integer)"
    if isinstance(value, numbers.Real):
        return f"{float(value)!r} (a float)"
    return f"{value!r} (a {type(value).__name__})"


def _is_real(value: Any) -> bool:
    """True for int and float (and numpy numbers), False for bool and anything else."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


def _is_integer(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool | np.bool_)


def _real(value: Any, key: str, *, minimum: float | None = None,
          strict: bool = False, what: str = "a finite number") -> float:
    """Check one finite real number, optionally ``> minimum`` (strict) or ``>= minimum``."""
    if not _is_real(value):
        raise _FieldError(key, f"expected {what}, found {_describe(value)}")
    number = float(value)
    if not math.isfinite(number):
        raise _FieldError(key, f"expected {what}, found {number!r}")
    if minimum is not None and (number <= minimum if strict else number < minimum):
        raise _FieldError(key, f"expected {what}, found {number!r}")
    return number


def _integer(value: Any, key: str, minimum: int, what: str) -> int:
    """Check an integer (not a bool, not a float) ``>= minimum``."""
    if not _is_integer(value) or int(value) < minimum:
        raise _FieldError(key, f"expected {what}, found {_describe(value)}")
    return int(value)


def _real_vector(value: Any, n: int | None, key: str, what: str,
                 *, minimum: float | None = None, strict: bool = False) -> tuple[float, ...]:
    """Check an array of ``n`` (any number if ``None``) finite reals.

    ``what`` describes the whole array, e.g. ``"an array of 2 finite numbers [lower, upper]"``.
    """
    if isinstance(value, np.ndarray):
        if value.ndim != 1:
            raise _FieldError(key, f"expected {what}, found an array of shape {value.shape}")
        value = value.tolist()
    if not isinstance(value, list | tuple):
        raise _FieldError(key, f"expected {what}, found {_describe(value)}")
    if n is not None and len(value) != n:
        raise _FieldError(key, f"expected {what}, found {_describe(value)}")
    out = []
    for i, item in enumerate(value):
        if not _is_real(item):
            raise _FieldError(key, f"expected {what}, element {i} is {_describe(item)}")
        number = float(item)
        bad = not math.isfinite(number) or (
            minimum is not None and (number <= minimum if strict else number < minimum))
        if bad:
            raise _FieldError(key, f"expected {what}, element {i} is {number!r}")
        out.append(number)
    return tuple(out)


def _as_time(t: float | np.ndarray) -> np.ndarray:
    return np.asarray(t, dtype=np.float64)


# ---------------------------------------------------------------------------
# reference kinds
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class HarmonicReference:
    """Harmonic reference, the seed paper's Table 1.

    .. math::

        r(t) = \\begin{pmatrix} c_x + s_x \\sin\\omega t + k_x \\cos\\omega t \\\\
                                c_y + s_y \\sin\\omega t + k_y \\cos\\omega t \\end{pmatrix},
        \\qquad
        \\dot r(t) = \\omega \\begin{pmatrix} s_x \\cos\\omega t - k_x \\sin\\omega t \\\\
                                          s_y \\cos\\omega t - k_y \\sin\\omega t \\end{pmatrix}.

    Parameters
    ----------
    omega
        Angular frequency :math:`\\omega`, rad/s (any finite value).
    x, y
        Coefficients ``(c, s, k)`` of each coordinate, m.
    """

    omega: float
    x: tuple[float, float, float]
    y: tuple[float, float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "omega", _real(self.omega, "omega"))
        for name in ("x", "y"):
            coeffs = _real_vector(getattr(self, name), 3, name,
                                  "an array of 3 finite numbers [c, s, k]")
            object.__setattr__(self, name, coeffs)

    def position(self, t: float | np.ndarray) -> np.ndarray:
        """Reference position, shape ``np.shape(t) + (2,)``, m."""
        wt = self.omega * _as_time(t)
        s, c = np.sin(wt), np.cos(wt)
        cx, sx, kx = self.x
        cy, sy, ky = self.y
        return np.stack((cx + sx * s + kx * c, cy + sy * s + ky * c), axis=-1)

    def velocity(self, t: float | np.ndarray) -> np.ndarray:
        """Analytic time derivative of :meth:`position`, shape ``np.shape(t) + (2,)``, m/s."""
        wt = self.omega * _as_time(t)
        s, c = np.sin(wt), np.cos(wt)
        _, sx, kx = self.x
        _, sy, ky = self.y
        w = self.omega
        return np.stack((w * (sx * c - kx * s), w * (sy * c - ky * s)), axis=-1)

    def to_dict(self) -> dict[str, Any]:
        """The scenario file's inline-table form."""
        return {"type": "harmonic", "omega": self.omega, "x": list(self.x), "y": list(self.y)}


@dataclass(frozen=True, init=False, repr=False)
class PointReference:
    """Fixed goal :math:`r(t) = p`, :math:`\\dot r(t) = 0` (``type = "point"``).

    Parameters
    ----------
    position
        Goal ``(x, y)``, m: the scenario file's key ``position``. It is stored
        as :attr:`goal`, because ``position(t)`` is the method every reference
        kind evaluates.

    Examples
    --------
    >>> PointReference(position=(3.0, 0.0)).position(10.0)
    array([3., 0.])
    """

    goal: tuple[float, float]

    def __init__(self, position: Sequence[float] | np.ndarray) -> None:
        xy = _real_vector(position, 2, "position", "an array of 2 finite numbers [x, y]")
        object.__setattr__(self, "goal", xy)

    def __repr__(self) -> str:
        return f"PointReference(position={self.goal!r})"

    @property
    def position_xy(self) -> tuple[float, float]:
        """Deprecated name of :attr:`goal` (warns ``DeprecationWarning``)."""
        warnings.warn("PointReference.position_xy is deprecated; use PointReference.goal "
                      "(the constructor takes position=...)", DeprecationWarning, stacklevel=2)
        return self.goal

    def position(self, t: float | np.ndarray) -> np.ndarray:
        """The goal repeated, shape ``np.shape(t) + (2,)``, m."""
        return np.broadcast_to(np.asarray(self.goal), np.shape(t) + (2,)).copy()

    def velocity(self, t: float | np.ndarray) -> np.ndarray:
        """Zeros, shape ``np.shape(t) + (2,)``, m/s."""
        return np.zeros(np.shape(t) + (2,))

    def to_dict(self) -> dict[str, Any]:
        """The scenario file's inline-table form."""
        return {"type": "point", "position": list(self.goal)}


@dataclass(frozen=True)
class WaypointReference:
    """Piecewise-linear reference through waypoints.

    With times :math:`t_0 < \\dots < t_{M-1}` and points :math:`p_0, \\dots, p_{M-1}`,

    .. math::

        r(t) = \\begin{cases}
            p_0 & t \\le t_0 \\\\
            p_i + \\frac{t - t_i}{t_{i+1} - t_i} (p_{i+1} - p_i) & t_i \\le t \\le t_{i+1} \\\\
            p_{M-1} & t \\ge t_{M-1}
        \\end{cases}

    and :math:`\\dot r(t) = (p_{i+1} - p_i) / (t_{i+1} - t_i)` on
    :math:`t_i \\le t < t_{i+1}` (the slope of the segment that starts at a
    breakpoint), zero before :math:`t_0` and from :math:`t_{M-1}` on.

    Parameters
    ----------
    times
        Strictly increasing finite times, s (at least one).
    points
        One ``(x, y)`` per time, m.
    """

    times: tuple[float, ...]
    points: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        times = _real_vector(self.times, None, "times",
                             "a non-empty array of finite, strictly increasing times")
        if isinstance(self.points, np.ndarray):
            raw_points = list(self.points)
        elif isinstance(self.points, list | tuple):
            raw_points = self.points
        else:
            raise _FieldError("points", "expected an array of [x, y] pairs, found "
                              + _describe(self.points))
        points = tuple(
            _real_vector(p, 2, f"points[{i}]", "an array of 2 finite numbers [x, y]")
            for i, p in enumerate(raw_points)
        )
        if not points:
            raise _FieldError("points", "expected at least one [x, y] point, found an empty array")
        if len(times) != len(points):
            raise _FieldError("times", f"expected one time per point ({len(points)} points), "
                              f"found {len(times)} times")
        steps = np.diff(times)
        if np.any(steps <= 0.0):
            i = int(np.argmax(steps <= 0.0))
            raise _FieldError("times", "expected strictly increasing times, found "
                              f"times[{i}] = {times[i]!r} followed by {times[i + 1]!r}")
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "points", points)

    def _arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.times), np.asarray(self.points).reshape(-1, 2)

    def position(self, t: float | np.ndarray) -> np.ndarray:
        """Interpolated position, shape ``np.shape(t) + (2,)``, m."""
        t = _as_time(t)
        times, points = self._arrays()
        return np.stack((np.interp(t, times, points[:, 0]),
                         np.interp(t, times, points[:, 1])), axis=-1)

    def velocity(self, t: float | np.ndarray) -> np.ndarray:
        """Piecewise-constant slope, shape ``np.shape(t) + (2,)``, m/s."""
        t = _as_time(t)
        times, points = self._arrays()
        if times.size < 2:
            return np.zeros(t.shape + (2,))
        slopes = np.diff(points, axis=0) / np.diff(times)[:, None]
        segment = np.searchsorted(times, t, side="right") - 1
        inside = (segment >= 0) & (segment < times.size - 1)
        picked = slopes[np.clip(segment, 0, times.size - 2)]
        return np.where(inside[..., None], picked, 0.0)

    def to_dict(self) -> dict[str, Any]:
        """The scenario file's inline-table form."""
        return {"type": "waypoints", "times": list(self.times),
                "points": [list(p) for p in self.points]}


Reference = HarmonicReference | PointReference | WaypointReference
"""Any reference kind (a type alias usable with ``isinstance``)."""


class ReferenceSet:
    """Several references evaluated together (the hot path of the controllers).

    Harmonic and point references are evaluated for all robots at once with
    the same arithmetic as their own :meth:`position` (identical values);
    waypoint references one by one.

    Parameters
    ----------
    references
        One reference per robot.
    """

    def __init__(self, references: Sequence[Reference]) -> None:
        self.references = tuple(references)
        m = len(self.references)
        harmonic = [i for i, r in enumerate(self.references) if isinstance(r, HarmonicReference)]
        points = [i for i, r in enumerate(self.references) if isinstance(r, PointReference)]
        self._others = [i for i in range(m) if i not in harmonic and i not in points]
        self._harmonic = slice(None) if len(harmonic) == m else np.array(harmonic, dtype=np.int64)
        self._n_harmonic = len(harmonic)
        self._all_harmonic = len(harmonic) == m
        # per robot (column vectors): omega, then c, s, k of x and of y
        coeffs = np.array([(r.omega,) + r.x + r.y for r in self.references
                           if isinstance(r, HarmonicReference)]).reshape(-1, 7)
        self._coeffs = tuple(coeffs[:, i:i + 1] for i in range(7))
        self._coeff_table = np.ascontiguousarray(coeffs)
        self._points = slice(None) if len(points) == m else np.array(points, dtype=np.int64)
        self._n_points = len(points)
        self._point_xy = np.array([self.references[i].goal for i in points]
                                  ).reshape(-1, 1, 2)

    def positions(self, times: np.ndarray) -> np.ndarray:
        """Positions ``(m, T, 2)`` of every reference at ``times (T,)``, m."""
        times = _as_time(times)
        if self._all_harmonic and times.ndim == 1:  # hot path: one kernel
            out = np.empty((self._n_harmonic, times.shape[0], 2))
            harmonic_positions(self._coeff_table, times, out)
            return out
        out = np.empty((len(self.references),) + times.shape + (2,))
        if self._n_harmonic:
            omega, cx, sx, kx, cy, sy, ky = self._coeffs
            wt = omega * times
            s, c = np.sin(wt), np.cos(wt)
            out[self._harmonic, :, 0] = cx + sx * s + kx * c
            out[self._harmonic, :, 1] = cy + sy * s + ky * c
        if self._n_points:
            out[self._points] = self._point_xy
        for i in self._others:
            out[i] = self.references[i].position(times)
        return out


_EXPECTED = {
    "omega": "a finite number (rad/s)",
    "x": "an array of 3 finite numbers [c, s, k]",
    "y": "an array of 3 finite numbers [c, s, k]",
    "position": "an array of 2 finite numbers [x, y]",
    "times": "an array of strictly increasing finite times",
    "points": "an array of [x, y] points, one per time",
}

_KINDS: dict[str, tuple[type, tuple[str, ...]]] = {
    "harmonic": (HarmonicReference, ("omega", "x", "y")),
    "point": (PointReference, ("position",)),
    "waypoints": (WaypointReference, ("times", "points")),
}


def reference_from_dict(d: Mapping[str, Any], source: str, key: str) -> Reference:
    """Build a reference from its scenario-file inline table.

    Parameters
    ----------
    d
        The table, e.g. ``{"type": "point", "position": [1.0, 2.0]}``.
    source
        File or built-in name, for error messages.
    key
        Key path of the table in the file, e.g. ``robots[0].reference``.

    Returns
    -------
    Reference
        The validated reference.

    Raises
    ------
    ScenarioError
        Not a table, missing or unknown ``type``, missing or unknown keys, or a
        bad value; the error's key is ``key`` or ``key.<subkey>``.
    """
    expected = ("an inline table such as { type = \"point\", position = [x, y] } with type "
                "one of " + ", ".join(repr(k) for k in _KINDS))
    if not isinstance(d, Mapping):
        raise ScenarioError(source, key, f"expected {expected}, found {_describe(d)}")
    if "type" not in d:
        raise ScenarioError(source, f"{key}.type", f"missing required key; expected {expected}")
    kind = d["type"]
    if not isinstance(kind, str) or kind not in _KINDS:
        raise ScenarioError(source, f"{key}.type",
                            "expected one of " + ", ".join(repr(k) for k in _KINDS)
                            + f", found {_describe(kind)}")
    cls, fields = _KINDS[kind]
    allowed = ("type",) + fields
    for name in d:
        if name not in allowed:
            raise ScenarioError(source, f"{key}.{name}",
                                f"unknown key for a {kind!r} reference; allowed keys: "
                                + ", ".join(allowed))
    for name in fields:
        if name not in d:
            raise ScenarioError(source, f"{key}.{name}",
                                f"missing required key of a {kind!r} reference; expected "
                                f"{_EXPECTED[name]}")
    try:
        return cls(*(d[name] for name in fields))
    except _FieldError as exc:
        raise ScenarioError(source, f"{key}.{exc.key}", exc.detail) from None
