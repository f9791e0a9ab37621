"""Compiled kernels of the liveness rules (:mod:`sqpmpc.rules`): turn limits, held rows,
stall and parking repairs, gear cycles, detours and the roundabout's directions.

They live in the kernel layer so that the collision kernels and the warm-up never import
the rules; the rules call them.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "detour_step", "gear_streak", "hold_touching_rows", "idle", "inside_pairs",
    "limit_turning", "parking_mask",
    "repair_guess", "repair_speeds", "reversing", "roundabout_directions",
    "stall_repair", "standing_still",
    "warm_up_roundabout", "warm_up_rules",
]


_jit = numba.njit(cache=True, nogil=True)


@_jit
def gear_streak(last: float, before: float, speed: float, streak: int) -> int:
    """The robot's count of gear reversals in a row that make no headway, after a
    sample: ``streak + 1`` when the speeds applied at ``k-2`` (``before``) and ``k-1``
    (``last``) have opposite signs and net less than ``speed`` on average, else 0."""
    if last * before < 0.0 and abs(last + before) < 2.0 * speed:
        return streak + 1
    return 0


@_jit
def idle(last: float, streak: int, speed: float, cycle: int) -> bool:
    """Whether a robot makes no headway: its last applied speed ``|last| < speed``, or
    it has reversed gear ``cycle`` samples in a row with no net motion (``streak``,
    :func:`gear_streak`). Plain RTI at a neighbour can command ``+0.3, -0.3, +0.3, ...``
    m/s for ever (the pair at the distance its rows keep, the robots needing to turn
    round): such a robot stays where it is as surely as a stopped one (the stall-repair
    and detour rules' "standing")."""
    return abs(last) < speed or streak >= cycle


@_jit
def limit_turning(n0x: float, n0y: float, normals: np.ndarray, max_turn: float) -> None:
    r"""Limit the turn of a pair's normal between consecutive stages (in place).

    ``normals (N, 2)`` are the unit normals of stages 1..N; stage 0 is the
    current normal ``(n0x, n0y)``. A normal turning by more than ``max_turn``
    from the previous (already limited) one is replaced by the previous one
    rotated by ``max_turn`` towards it (counter-clockwise when exactly
    opposite). See :class:`sqpmpc.rules.liveness.TurnLimit`.
    """
    cos_max = math.cos(max_turn)
    c, s = math.cos(max_turn), math.sin(max_turn)
    px, py = n0x, n0y
    for i in range(normals.shape[0]):
        cx, cy = normals[i, 0], normals[i, 1]
        if px * cx + py * cy < cos_max:
            if px * cy - py * cx < 0.0:
                cx, cy = c * px + s * py, -s * px + c * py
            else:
                cx, cy = c * px - s * py, s * px + c * py
            normals[i, 0], normals[i, 1] = cx, cy
        px, py = cx, cy


@_jit
def hold_touching_rows(me: np.ndarray, touching: np.ndarray, A_out: np.ndarray,
                     lower_out: np.ndarray) -> None:
    """Touching pairs (``touching (E,)``) repeat the stage-1 row on stage 2, in place."""
    if A_out.shape[1] < 2:
        return
    for e in range(touching.shape[0]):
        if touching[e]:
            A_out[e, 1, 0], A_out[e, 1, 1] = A_out[e, 0, 0], A_out[e, 0, 1]
            lower_out[e, 1] = A_out[e, 0, 0] * me[0] + A_out[e, 0, 1] * me[1]


@_jit
def repair_speeds(speeds: np.ndarray, goals: np.ndarray, states: np.ndarray,
                   only: np.ndarray, slow: float, distance: float, ahead_speed: float,
                   back_speed: float) -> int:
    """Set the guess speeds of stalled robots to ``ahead_speed``/``back_speed``; count them.

    A robot (``only[r]``) is stalled when every ``|speeds[r]| < slow`` and its
    goal is farther than ``distance``; it is linearized moving towards the goal
    (forward if the goal is not behind its heading), unless the bounds make
    that speed 0. ``slow`` is at most the repair speeds' size, so a robot
    already at the (clipped) repair speed is not "stalled".
    """
    repaired = 0
    for r in range(speeds.shape[0]):
        if not only[r]:
            continue
        fastest = 0.0
        for i in range(speeds.shape[1]):
            fastest = max(fastest, abs(speeds[r, i]))
        if not fastest < slow:
            continue
        gx, gy = goals[r, 0] - states[r, 0], goals[r, 1] - states[r, 1]
        if not np.hypot(gx, gy) > distance:
            continue
        ahead = gx * np.cos(states[r, 2]) + gy * np.sin(states[r, 2]) >= 0.0
        speed = ahead_speed if ahead else back_speed
        if speed == 0.0:  # the bounds forbid that direction: nothing to repair
            continue
        speeds[r, :] = speed
        repaired += 1
    return repaired


@_jit
def _repair_robot(out: np.ndarray, r: int, references: np.ndarray, states: np.ndarray,
                  limit: float, distance: float, ahead_speed: float, back_speed: float) -> bool:
    """:func:`repair_speeds` of robot ``r`` on ``out`` (goal ``references[r, -1]``)."""
    fastest = 0.0
    for i in range(out.shape[1]):
        fastest = max(fastest, abs(out[r, i]))
    if not fastest < limit:
        return False
    last = references.shape[1] - 1
    gx, gy = references[r, last, 0] - states[r, 0], references[r, last, 1] - states[r, 1]
    if not np.hypot(gx, gy) > distance:
        return False
    ahead = gx * np.cos(states[r, 2]) + gy * np.sin(states[r, 2]) >= 0.0
    speed = ahead_speed if ahead else back_speed
    if speed == 0.0:  # the bounds forbid that direction: nothing to repair
        return False
    out[r, :] = speed
    return True


@_jit
def repair_guess(guess: np.ndarray, references: np.ndarray, states: np.ndarray,
                 only: np.ndarray, slow: float, distance: float, ahead_speed: float,
                 back_speed: float, out: np.ndarray) -> int:
    """The guess speeds ``(m, N)`` into ``out`` with the stalled robots among ``only``
    repaired (:func:`repair_speeds` with the goals ``references[:, -1]``); count them."""
    out[:, :] = guess
    repaired = 0
    for r in range(out.shape[0]):
        if only[r] and _repair_robot(out, r, references, states, slow, distance, ahead_speed,
                                     back_speed):
            repaired += 1
    return repaired


@_jit
def stall_repair(guess: np.ndarray, references: np.ndarray, applied: np.ndarray,
                 applied_before: np.ndarray, states: np.ndarray, params: np.ndarray,
                 still_for: np.ndarray, cycling: np.ndarray, stuck: np.ndarray,
                 out: np.ndarray) -> int:
    """The stall repair in one call: :func:`standing_still`, then the guess speeds
    ``(m, N)`` into ``out`` with the robots repaired (a stuck one at any speed, the
    others when every ``|v| < slow``, as :func:`repair_speeds`); returns how many.

    ``params``: ``(speed, patience, distance, slow, ahead_speed, back_speed, cycle)``.
    """
    standing_still(references, applied, applied_before, params[0], np.int64(params[1]),
                   np.int64(params[6]), still_for, cycling, stuck)
    out[:, :] = guess
    repaired = 0
    for r in range(out.shape[0]):
        limit = np.inf if stuck[r] else params[3]
        if _repair_robot(out, r, references, states, limit, params[2], params[4], params[5]):
            repaired += 1
    return repaired


@_jit
def standing_still(references: np.ndarray, applied: np.ndarray, applied_before: np.ndarray,
                   speed: float, patience: int, cycle: int, still_for: np.ndarray,
                   cycling: np.ndarray, stuck: np.ndarray) -> bool:
    """Count the samples each robot has been :func:`idle` (the speeds ``[:, 0]`` of the
    inputs ``(m, nu)`` applied at ``k-1`` and ``k-2``; ``cycling`` its
    :func:`gear_streak`, in place) with its references ``(m, N, 2)`` at rest
    (``still_for``, in place); ``stuck`` those at ``patience``."""
    any_stuck = False
    for r in range(references.shape[0]):
        rest = True
        for i in range(references.shape[1]):
            if (abs(references[r, i, 0] - references[r, 0, 0]) > 1e-9
                    or abs(references[r, i, 1] - references[r, 0, 1]) > 1e-9):
                rest = False
                break
        cycling[r] = gear_streak(applied[r, 0], applied_before[r, 0], speed, cycling[r])
        still = rest and idle(applied[r, 0], cycling[r], speed, cycle)
        still_for[r] = still_for[r] + 1 if still else 0
        stuck[r] = still_for[r] >= patience
        any_stuck = any_stuck or stuck[r]
    return any_stuck


@_jit
def parking_mask(raw: np.ndarray, positions: np.ndarray, radius: float,
                  out: np.ndarray) -> int:
    """Robots whose reference rests over the horizon within ``radius`` into ``out``.

    Returns the number of parking robots, negated minus one if the mask changed
    (``-1 - count``), so one call tells both.
    """
    changed = False
    count = 0
    for r in range(raw.shape[0]):
        rest = True
        for i in range(raw.shape[1]):
            if abs(raw[r, i, 0] - raw[r, 0, 0]) > 1e-9 or abs(raw[r, i, 1] - raw[r, 0, 1]) > 1e-9:
                rest = False
                break
        near = np.hypot(raw[r, -1, 0] - positions[r, 0], raw[r, -1, 1] - positions[r, 1])
        park = rest and near <= radius
        count += park
        if park != out[r]:
            changed = True
            out[r] = park
    return -1 - count if changed else count


@_jit
def reversing(v: np.ndarray, applied: np.ndarray, applied_before: np.ndarray, eps: float,
               out: np.ndarray) -> int:
    """Robots whose plan reverses gear a second sample in a row (speeds above ``eps``): the
    planned speeds ``v (m,)`` against the speeds ``[:, 0]`` of the inputs ``(m, nu)``
    applied at the last two samples."""
    count = 0
    for r in range(v.shape[0]):
        v1, v2 = applied[r, 0], applied_before[r, 0]
        moving = abs(v[r]) > eps and abs(v1) > eps and abs(v2) > eps
        out[r] = moving and np.sign(v[r]) == np.sign(v2) and np.sign(v[r]) != np.sign(v1)
        count += out[r]
    return count


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


def warm_up_rules() -> None:
    """Compile or load the rules' kernels with the array layouts the pipeline passes (the
    rules' sample view is read-only; their own state and outputs are not)."""
    speeds = np.zeros((2, 3))
    states = _read_only(np.zeros((2, 3)))
    references = _read_only(np.zeros((2, 3, 2)))
    applied = _read_only(np.zeros((2, 2)))
    repair_speeds(speeds, np.ones((2, 2)), states, np.ones(2, dtype=np.bool_), 0.05, 0.1,
                  0.05, -0.05)
    parking_mask(references, states, 1.0, np.zeros(2, dtype=np.bool_))
    # with velocity states (CONTRACT 1c) the rules see the poses as a strided view
    poses = _read_only(np.zeros((2, 5)))[:, :3]
    repair_speeds(speeds, np.ones((2, 2)), poses, np.ones(2, dtype=np.bool_), 0.05, 0.1,
                  0.05, -0.05)
    parking_mask(references, poses, 1.0, np.zeros(2, dtype=np.bool_))
    standing_still(references, applied, applied, 0.05, 10, 4, np.zeros(2, dtype=np.int64),
                   np.zeros(2, dtype=np.int64), np.zeros(2, dtype=np.bool_))
    # the guess speeds as the engine shows them: a read-only strided view of the iterate
    guess = _read_only(np.zeros(2 * 13)).reshape(2, 13)[:, 3:13:5]
    mask = np.zeros(2, dtype=np.bool_)
    for own in (states, poses):
        stall_repair(guess, references, applied, applied, own,
                     np.array([0.05, 10, 0.1, 0.05, 0.05, -0.05, 4]),
                     np.zeros(2, dtype=np.int64), np.zeros(2, dtype=np.int64), mask,
                     np.empty((2, 2)))
        repair_guess(guess, references, own, mask, 0.05, 0.01, 0.05, -0.05, np.empty((2, 2)))
    limit_turning(1.0, 0.0, np.zeros((2, 2)), 0.6)
    for me in (np.zeros(2), _read_only(np.zeros(2))):
        hold_touching_rows(me, np.zeros(1, dtype=np.bool_), np.zeros((1, 2, 2)),
                           np.zeros((1, 2)))
    reversing(_read_only(np.zeros(2)), applied, applied, 0.005, np.zeros(2, dtype=np.bool_))
    detour_step(_read_only(np.zeros((3, 2))), np.arange(2), applied, applied, references,
                np.ones((2, 3)), np.array([0.05, 0.3, 0.2, 2, 6, 4]),
                np.zeros((4, 2), dtype=np.int64))


@_jit
def detour_step(positions: np.ndarray, own: np.ndarray, applied: np.ndarray,
                applied_before: np.ndarray, references: np.ndarray, required: np.ndarray,
                params: np.ndarray, state: np.ndarray) -> int:
    """Advance the detour state of the own robots by one sample; returns the new
    activations, or ``-1`` when no robot detours after the step.

    ``required (m, n)`` are the own robots' required distances to everyone, their goals
    the stage-N references ``references[:, -1]``; a robot is blocked while :func:`idle`
    (the speeds of ``applied`` and ``applied_before``, samples ``k-1`` and ``k-2``);
    ``params`` are ``(speed, reach, cos_cone, patience, hold, cycle)``; the rows of
    ``state (4, m)`` (samples blocked, samples of detour left, blocker, gear streak) are
    updated in place (see :class:`Detour`).
    """
    speed, reach, cos_cone = params[0], params[1], params[2]
    patience, hold, cycle = np.int64(params[3]), np.int64(params[4]), np.int64(params[5])
    blocked_for, active_for, blocker, cycling = state[0], state[1], state[2], state[3]
    last = references.shape[1] - 1
    activations = 0
    detouring = False
    for r in range(own.shape[0]):
        i = own[r]
        px, py = positions[i, 0], positions[i, 1]
        gx, gy = references[r, last, 0] - px, references[r, last, 1] - py
        goal_dist = np.hypot(gx, gy)
        blocked = False
        closest = -1
        best = np.inf
        cycling[r] = gear_streak(applied[r, 0], applied_before[r, 0], speed, cycling[r])
        if idle(applied[r, 0], cycling[r], speed, cycle) and goal_dist > reach:
            for j in range(positions.shape[0]):
                if j == i:
                    continue
                rx, ry = positions[j, 0] - px, positions[j, 1] - py
                d = np.hypot(rx, ry)
                cos = (rx * gx + ry * gy) / max(d * goal_dist, 1e-12)
                if d < required[r, j] + reach and cos > cos_cone:
                    blocked = True
                    if d < best:
                        best, closest = d, j
        blocked_for[r] = blocked_for[r] + 1 if blocked else 0
        if blocked and blocked_for[r] >= patience:
            if active_for[r] == 0:
                activations += 1
            blocker[r] = closest
            active_for[r] = hold
        else:
            active_for[r] = max(active_for[r] - 1, 0)
        detouring = detouring or active_for[r] != 0
    return activations if detouring else -1


@_jit
def roundabout_directions(positions: np.ndarray, headings: np.ndarray,
                          rest_goals: np.ndarray, own: np.ndarray, goals: np.ndarray,
                          required: np.ndarray, sense: float, cos_cone: float,
                          cos_along: float, min_crowd: int, goal_distance: float,
                          directions: np.ndarray) -> int:
    """The roundabout direction of every own robot, or zeros where the rule is idle.

    Parameters
    ----------
    positions, headings
        ``(n, 2)`` positions and ``(n,)`` headings of all robots.
    rest_goals
        ``(n, 2)`` where each robot's reference comes to rest at the end of the
        scenario (NaN for references still moving then): a robot within
        ``goal_distance`` of it has arrived and is not part of a crowd.
    own
        ``(m,)`` indices of the own robots in ``positions``.
    goals
        ``(m, 2)`` the own robots' goals (stage-``N`` scenario references).
    required
        ``(m, n)`` required distances from the own robots to everyone.
    sense, cos_cone, cos_along, min_crowd, goal_distance
        See :class:`Roundabout` (``cos_cone`` and ``cos_along`` are the cosines
        of ``cone`` and ``along``).
    directions
        ``(m, 2)`` output: unit directions, or ``(0, 0)`` for robots that
        track their goal.

    Returns
    -------
    int
        How many own robots follow a roundabout direction.
    """
    n = positions.shape[0]
    member = np.zeros(n, dtype=np.bool_)
    active = 0
    for r in range(own.shape[0]):
        i = own[r]
        directions[r, 0] = 0.0
        directions[r, 1] = 0.0
        px, py = positions[i, 0], positions[i, 1]
        gx, gy = goals[r, 0] - px, goals[r, 1] - py
        goal_dist = math.hypot(gx, gy)
        if not goal_dist > goal_distance:
            continue
        ux, uy = gx / goal_dist, gy / goal_dist
        reach = min(sense, goal_dist)
        count = 0
        cx, cy = 0.0, 0.0
        for j in range(n):
            member[j] = False
            if j == i:
                continue
            rx, ry = positions[j, 0] - px, positions[j, 1] - py
            d = math.hypot(rx, ry)
            if d > reach or rx * ux + ry * uy < d * cos_cone:
                continue
            if math.cos(headings[j]) * ux + math.sin(headings[j]) * uy > cos_along:
                continue  # heading the way this robot goes: traffic, not a conflict
            if math.hypot(positions[j, 0] - rest_goals[j, 0],
                          positions[j, 1] - rest_goals[j, 1]) <= goal_distance:
                continue  # arrived: an obstacle to pass, not a flow to join
            member[j] = True
            count += 1
            cx += positions[j, 0]
            cy += positions[j, 1]
        if count < min_crowd:
            continue
        cx /= count
        cy /= count
        rho = 0.0
        for j in range(n):
            if member[j]:
                rho = max(rho, math.hypot(positions[j, 0] - cx, positions[j, 1] - cy)
                          + required[r, j])
        wx, wy = cx - px, cy - py
        w = math.hypot(wx, wy)
        if w > rho:
            wx, wy = wx / w, wy / w
            beta = math.asin(rho / w)
            gamma = math.atan2(wx * uy - wy * ux, wx * ux + wy * uy)
            if gamma <= -beta or gamma >= beta:
                continue  # the straight path clears the crowd
            c, s = math.cos(beta), math.sin(beta)
            directions[r, 0], directions[r, 1] = c * wx + s * wy, -s * wx + c * wy
        else:  # inside the crowd: counter-clockwise around its centre
            if w > 1e-9:
                wx, wy = wx / w, wy / w
            else:
                wx, wy = ux, uy
            directions[r, 0], directions[r, 1] = wy, -wx
        active += 1
    return active


def warm_up_roundabout() -> None:
    """Compile or load the rule's kernel with the array layouts the rule passes."""
    roundabout_directions(_read_only(np.zeros((3, 2))), _read_only(np.zeros(3)),
                          np.full((3, 2), np.nan), np.arange(2), np.ones((2, 2)),
                          np.ones((2, 3)), 3.0, 0.5, 0.7, 4, 1.0, np.zeros((2, 2)))


@_jit
def inside_pairs(me: np.ndarray, others_now: np.ndarray, shared: np.ndarray,
                 true_distance: np.ndarray, out: np.ndarray) -> int:
    """Shared slots whose pair is inside its true distance now into ``out (E,)`` bool;
    returns how many (the ``overlap-recovery`` check's slots, usually none).

    ``me (2,)`` and ``others_now (E, 2)`` are the measured positions; the distance is
    ``np.hypot`` of the differences, as
    :meth:`sqpmpc.ocp.collision_rows.ExternalCollisionModel.inside` documents (the
    ``overlap-recovery`` rule).
    """
    count = 0
    for e in range(others_now.shape[0]):
        gap = np.hypot(others_now[e, 0] - me[0], others_now[e, 1] - me[1])
        out[e] = shared[e] and gap < true_distance[e]
        count += out[e]
    return count
