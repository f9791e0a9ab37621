"""The compiled motion along a roadmap path (:mod:`sqpmpc.kernels.motion`) is the numpy
motion it replaced (``tests/motion_reference.py``) to the last bit: the smoothed path
and the timed motion, on random grid walks (turns, diagonals, steps back, repeated and
nearly repeated points) and on the edge cases one by one (a turn in place, a one-point
path, driving backwards, with and without an acceleration bound, projected within a
part of the path, stopping or not)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sqpmpc.coordination.motion import path_motion, smooth_path
from tests import motion_reference as reference

T = 0.2
V_MAX, W_MAX = 1.0, 1.5
REACHES = (0.0, 0.03, 0.06, 0.2)


def _walk(rng: np.random.Generator, steps: int, h: float = 0.5) -> np.ndarray:
    """A random walk on a grid with diagonals, some steps stretched, some points repeated
    (exactly, or within 1e-9)."""
    moves = np.array([[1, 0], [0, 1], [-1, 0], [0, -1], [1, 1], [1, -1]], dtype=float) * h
    points = [rng.normal(0.0, 1.0, 2)]
    for _ in range(steps):
        if rng.random() < 0.1:
            jitter = 0.0 if rng.random() < 0.5 else rng.normal(0.0, 1e-10, 2)
            points.append(points[-1] + jitter)
        else:
            stretch = 1.0 + 0.3 * rng.random() * (rng.random() < 0.3)
            points.append(points[-1] + moves[rng.integers(len(moves))] * stretch)
    return np.array(points)


def _same_path(points: np.ndarray, reach: float, step: float) -> None:
    want = reference.smooth_path(points, reach, step)
    got = smooth_path(points, reach, step)
    for w, g in zip(want, got, strict=True):
        assert w.shape == g.shape and w.dtype == g.dtype
        np.testing.assert_array_equal(g, w)


def _same_motion(*args: object, **kwargs: object) -> None:
    want = reference.path_motion(*args, **kwargs)
    got = path_motion(*args, **kwargs)
    np.testing.assert_array_equal(got.poses, want.poses)
    np.testing.assert_array_equal(got.velocities, want.velocities)


@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_motion_is_the_numpy_one_on_random_paths(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for trial in range(150):
        points = _walk(rng, int(rng.integers(0, 8)))
        reach = REACHES[trial % len(REACHES)]
        _same_path(points, reach, 0.05)
        near = points[rng.integers(len(points))]
        pose = np.r_[near + rng.normal(0.0, 0.1 * rng.choice([0.0, 1.0, 5.0]), 2),
                     rng.uniform(-7.0, 7.0)]
        speed = float(rng.choice([0.0, rng.uniform(-1.0, 1.2)]))
        acceleration = None if rng.random() < 0.4 else float(rng.uniform(0.3, 3.0))
        within = None if rng.random() < 0.4 else int(rng.integers(0, len(points) + 2))
        turn_rate = None if rng.random() < 0.5 else float(rng.uniform(-1.0, 1.0))
        _same_motion(points, pose, speed, reach, T, int(rng.integers(1, 30)), V_MAX, W_MAX,
                     acceleration, stop=bool(rng.random() < 0.6), within=within,
                     reverse=bool(rng.random() < 0.25), turn_rate=turn_rate)


EDGES = {
    "half-turn": [[0.0, 0.0], [0.5, 0.0], [0.0, 0.0], [0.0, 0.5]],
    "half-turns": [[0.0, 0.0], [0.5, 0.0], [0.0, 0.0], [0.5, 0.0], [0.5, 0.5]],
    "repeated": [[0.0, 0.0], [0.0, 0.0], [0.5, 0.0], [0.5, 0.0], [0.5, 0.5]],
    "all-one-point": [[0.3, 0.2], [0.3, 0.2], [0.3, 0.2]],
    "one-point": [[0.3, 0.2]],
    "two-points": [[0.0, 0.0], [0.5, 0.0]],
    "right-angles": [[0.0, 0.0], [0.5, 0.0], [0.5, 0.5], [1.0, 0.5], [1.0, 0.0]],
    "diagonals": [[0.0, 0.0], [0.5, 0.5], [1.0, 0.0], [1.5, 0.5], [1.5, 1.0]],
    "straight": [[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [1.5, 0.0]],
    "short": [[0.0, 0.0], [1e-6, 0.0], [1e-6, 1e-6]],
}
POSES = ([0.0, 0.0, 0.0], [0.1, 0.05, 3.0], [0.5, 0.0, -math.pi], [0.3, 0.2, 0.5])


@pytest.mark.parametrize("name", sorted(EDGES))
@pytest.mark.parametrize("acceleration", [None, 0.5, 2.0])
def test_the_compiled_motion_is_the_numpy_one_on_edge_cases(
        name: str, acceleration: float | None) -> None:
    points = np.array(EDGES[name])
    for reach in REACHES:
        _same_path(points, reach, 0.05)
        for pose in POSES:
            for speed in (0.0, 0.4, -0.3):
                for stop, turn_rate in ((True, None), (False, None), (True, 0.3)):
                    for within in (None, 1, 10):
                        for reverse in (False, True):
                            _same_motion(points, np.array(pose), speed, reach, T, 12, V_MAX,
                                         W_MAX, acceleration, stop=stop, within=within,
                                         reverse=reverse, turn_rate=turn_rate)

def test_the_motion_is_written_into_the_arrays_given() -> None:
    poses, velocities = np.zeros((13, 3)), np.zeros((13, 2))
    points = np.array(EDGES["right-angles"])
    motion = path_motion(points, np.zeros(3), 0.2, 0.06, T, 12, V_MAX, W_MAX, 1.0,
                         out=(poses, velocities))
    assert motion.poses is poses and motion.velocities is velocities
    want = reference.path_motion(points, np.zeros(3), 0.2, 0.06, T, 12, V_MAX, W_MAX, 1.0)
    np.testing.assert_array_equal(poses, want.poses)
    np.testing.assert_array_equal(velocities, want.velocities)
