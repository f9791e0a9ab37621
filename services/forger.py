"""A hostile process for tests and benchmarks: well-formed messages on other processes' keys.

``python -m services.forger --scenario S --run R --connect EP [--credentials DIR
--identity robot-2 | --zenoh-config FILE] [--attack cmd,plan,state,done,alive]
[--target 1] [--duration S] [--zenoh-mode peer|client]``

It joins a run like any process (with whatever credentials it was given,
possibly none) and, for ``--duration`` seconds, publishes:

- ``cmd``: an input for robot ``--target`` on ``robot/<target>/cmd`` for the
  newest sample it saw (or every sample when it sees none) that steers it
  towards the nearest other robot at a distinctive speed
  (:data:`FORGED_SPEED` of the upper bound, so the plant's record shows
  where it was applied: :func:`forged_speed`);
- ``plan``: a plan of robot ``--target`` 10 m away from where it is, on
  ``robot/<target>/plan`` and addressed to every other robot;
- ``state``: the plant's states of the next sample with every robot moved
  by (1.0, 0.5) m;
- ``done``: the plant's end of run (once, at sample 3 or later, or after
  2 s when it sees no state, once it has ``--links`` links);
- ``alive``: the liveliness token of robot ``--target``;
- ``settings``: once, at the first state of sample ``--at`` or later it sees,
  an input for robot ``--target`` of that sample plus ``--sample-offset``
  (default -1: one the plant has already applied) carrying another settings
  digest and settings (what a controller started with other settings
  sends); with robot ``--target``'s own credentials the access control
  lets it through;
- ``freeze`` and ``herd`` (against ``sqpmpc robot --ros2``, with robot
  ``--target``'s own key): it reads every robot's plans and, as soon as a
  neighbour's plan comes, sends a plan of robot ``--target`` stamped at that
  neighbour's next instant (one plan per neighbour, many per sample), standing
  where the neighbour will then be (``freeze``) or 0.35 m ahead of it on its
  heading (``herd``);
- ``flood``: as fast as it can (no pause between rounds), robot ``--target``'s
  own ``cmd`` and ``plan`` (also addressed to every other robot) of the newest
  sample, well formed, or with ``--flood-bytes N`` payloads of ``N`` bytes.

It subscribes to ``plant/state`` to learn the samples (a process without
credentials sees nothing), prints ``{"ready": true}`` once its session is
open and one JSON line when it ends (after ``--duration`` or on SIGTERM):
the states it saw and the messages it sent. ``docs/security.md`` and
``tests/test_security.py`` use it.
"""

from __future__ import annotations

import argparse
import json
import queue
import sys
import threading
import time

import numpy as np
import zenoh

from sqpmpc.errors import ProblemError

from .credentials import config_for
from .messages import CmdMsg, DoneMsg, InvalidMessage, PlanMsg, StateMsg, decode, encode
from .node import (
    add_common_arguments,
    install_signal_handlers,
    scenario_digest,
    scenario_from_args,
)
from .ros2.timing import arc
from .transport import make_config, run_prefix

__all__ = ["ATTACKS", "FORGED_SPEED", "build_parser", "forged_input", "forged_speed", "main"]

PROG = "services.forger"
ATTACKS = ("cmd", "plan", "state", "done", "alive", "settings", "flood", "freeze", "herd")
"""What the forger can send."""
FORGED_SPEED = 0.987654321
"""Forged speed as a fraction of the upper speed bound."""


HERD_AHEAD = 0.35
"""``herd``: how far ahead of a neighbour on its heading the forged plan stands, m."""


def forged_speed(upper: np.ndarray) -> float:
    """The speed of every forged ``cmd``, given the scenario's upper input bounds."""
    return FORGED_SPEED * float(upper[0])


def forged_input(x: np.ndarray, target: int, upper: np.ndarray) -> np.ndarray:
    """A forged input for robot index ``target`` at states ``x`` (n x 3): the forged
    speed, turning as fast as allowed towards the nearest other robot."""
    d = np.delete(x[:, :2] - x[target, :2], target, axis=0)
    dx, dy = d[np.argmin(np.hypot(d[:, 0], d[:, 1]))]
    err = (np.arctan2(dy, dx) - x[target, 2] + np.pi) % (2.0 * np.pi) - np.pi
    return np.array([forged_speed(upper), float(np.clip(2.0 * err, -upper[1], upper[1]))])


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.forger``."""
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    add_common_arguments(parser)
    parser.add_argument("--identity", default="viewer",
                        help="with --credentials: whose certificate to use (e.g. robot-2)")
    parser.add_argument("--attack", default=",".join(ATTACKS[:5]),
                        help=f"comma-separated, of {', '.join(ATTACKS)} (default all but "
                             "settings)")
    parser.add_argument("--target", type=int, default=1, help="robot whose keys to forge")
    parser.add_argument("--duration", type=float, default=10.0, help="seconds to forge for")
    parser.add_argument("--links", type=int, default=0,
                        help="send 'done' only once linked to this many processes")
    parser.add_argument("--at", type=int, default=3,
                        help="'settings': the first sample at or after which to send it")
    parser.add_argument("--sample-offset", type=int, default=-1,
                        help="'settings': the forged input's sample relative to the state seen")
    parser.add_argument("--flood-bytes", type=int, default=0,
                        help="'flood': payloads of this many bytes (default: well-formed "
                             "messages)")
    parser.add_argument("--period", type=float, default=0.001,
                        help="seconds between rounds (each round sends every attack again)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point; prints a JSON summary and returns 0 (2 on bad input)."""
    args = build_parser().parse_args(argv)
    attacks = [a for a in args.attack.split(",") if a]
    if not set(attacks) <= set(ATTACKS):
        print(f"{PROG}: error: --attack takes {', '.join(ATTACKS)}", file=sys.stderr)
        return 2
    scenario = scenario_from_args(PROG, args)
    prefix = run_prefix(args.run)
    try:
        conf = make_config(args.listen, args.connect, args.zenoh_mode,
                           config_for(args, args.identity))
        # an attacker retries its links fast: it is there before the run starts
        conf.insert_json5("connect/retry", '{"period_init_ms": 20, "period_max_ms": 100}')
        if args.zenoh_mode == "client":  # give up when no router accepts it
            conf.insert_json5("connect/timeout_ms", "5000")
        session = zenoh.open(conf)
    except (ProblemError, ValueError, zenoh.ZError) as exc:
        print(json.dumps({"opened": False, "error": str(exc).split(" at /")[0]}))
        return 0
    stop = threading.Event()
    install_signal_handlers(stop)
    inbox: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    ids = [int(i) for i in scenario.ids]
    target = ids.index(args.target)
    digest = scenario_digest(scenario)
    upper = scenario.bounds.input_upper()
    sent = dict.fromkeys(attacks, 0)
    seen: set[int] = set()  # distinct samples (the plant may publish one again)
    links = 0
    last: StateMsg | None = None
    done_sent = False
    token = None

    reported: tuple[int, int, bool] = (0, 0, False)
    bulk = bytes(max(args.flood_bytes, 0))
    flooded = 0

    begun = time.monotonic()

    def report() -> None:
        print(json.dumps({"opened": True, "states_seen": len(seen), "links": links,
                          "sent": sent, "newest": last.sample if last else None,
                          "flood_bytes": flooded,
                          "seconds": round(time.monotonic() - begun, 3)}),
              flush=True)

    def put(payload: bytes, key: str, block: bool = False) -> None:
        # dropped when congested, unless ``block`` (a message that must arrive)
        session.put(f"{prefix}/{key}", payload, express=True,
                    congestion_control=zenoh.CongestionControl.BLOCK if block
                    else zenoh.CongestionControl.DROP)

    # the plant's states, not its own forged ones
    states = session.declare_subscriber(f"{prefix}/plant/state",
                                        lambda sample: inbox.put(sample.payload.to_bytes()),
                                        allowed_origin=zenoh.Locality.REMOTE)
    # ROS 2 mode: every robot's plans (its neighbours' instants and where they go)
    plans_in: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    plan_sub = session.declare_subscriber(
        f"{prefix}/robot/*/plan", lambda sample: plans_in.put(sample.payload.to_bytes()),
        allowed_origin=zenoh.Locality.REMOTE) if {"freeze", "herd"} & set(attacks) else None
    answered: set[tuple[int, float]] = set()  # (neighbour, its next instant) already sent
    try:
        if "alive" in attacks:
            token = session.liveliness().declare_token(f"{prefix}/alive/robot/{args.target}")
            sent["alive"] += 1
        print(json.dumps({"ready": True}), flush=True)
        start = time.monotonic()
        sample, polled = 0, 0.0
        while time.monotonic() < start + args.duration and not stop.is_set():
            if time.monotonic() - polled > 0.01:
                links = max(links, len(list(session.info.peers_zid()))
                            + len(list(session.info.routers_zid())))
                polled = time.monotonic()
            try:
                wait = 0.0 if "flood" in attacks else args.period
                msg = decode(inbox.get(timeout=wait) if wait else inbox.get_nowait(),
                             scenario.horizon)
                if isinstance(msg, StateMsg) and msg.scenario == digest:
                    seen.add(msg.sample)
                    if last is None or msg.sample >= last.sample:
                        last = msg
            except (queue.Empty, InvalidMessage):
                if last is None:  # blind: walk through every sample
                    sample = (sample + 1) % (scenario.steps + 1)
            k = last.sample if last is not None else sample
            x = last.x if last is not None else scenario.initial_states()
            if "cmd" in attacks:
                u = forged_input(x, target, upper)
                put(encode(CmdMsg(args.target, k, u, 0.0, None, 0)), f"robot/{args.target}/cmd")
                sent["cmd"] += 1
            if "plan" in attacks:
                far = np.repeat(x[target][None, :] + np.array([10.0, 10.0, 0.0]),
                                scenario.horizon + 1, axis=0)
                plan = encode(PlanMsg(args.target, k, k * scenario.sample_time, time.time(),
                                      far, np.zeros((scenario.horizon, 2))))
                put(plan, f"robot/{args.target}/plan")
                for rid in ids:
                    if rid != args.target:
                        put(plan, f"robot/{args.target}/plan/{rid}")
                sent["plan"] += 1
            while plan_sub is not None and not plans_in.empty():
                try:
                    other = decode(plans_in.get_nowait(), scenario.horizon)
                except (queue.Empty, InvalidMessage):
                    break
                if not isinstance(other, PlanMsg) or other.id == args.target:
                    continue
                nxt = other.stamp + scenario.sample_time  # when it decides next
                if (other.id, nxt) in answered:
                    continue
                answered.add((other.id, nxt))
                u = other.inputs[0]
                at = arc(other.states[0], float(u[0]), float(u[1]), scenario.sample_time)
                for kind in ("freeze", "herd"):
                    if kind not in attacks:
                        continue
                    stand = at.copy()
                    if kind == "herd":
                        stand[:2] += HERD_AHEAD * np.array([np.cos(at[2]), np.sin(at[2])])
                    plan = encode(PlanMsg(args.target, other.sample + 1,
                                          other.t + scenario.sample_time, nxt,
                                          np.repeat(stand[None, :], scenario.horizon + 1, 0),
                                          np.zeros((scenario.horizon, 2))))
                    put(plan, f"robot/{args.target}/plan", block=True)
                    put(plan, f"robot/{args.target}/plan/{other.id}", block=True)
                    sent[kind] += 1
            if "state" in attacks and k < scenario.steps:
                moved = x + np.array([1.0, 0.5, 0.0])
                put(encode(StateMsg(k + 1, (k + 1) * scenario.sample_time, tuple(ids), moved,
                                    None, digest)), "plant/state")
                sent["state"] += 1
            if "done" in attacks and not done_sent and (
                    k >= 3 if last is not None else time.monotonic() > start + 2.0) and (
                    links >= args.links):
                put(encode(DoneMsg(k, True)), "plant/done")
                sent["done"] += 1
                done_sent = True
            if "flood" in attacks:
                own = f"robot/{args.target}"
                if args.flood_bytes > 0:
                    payloads = [bulk] * 2
                else:
                    payloads = [encode(CmdMsg(args.target, k, np.zeros(2), 0.0, None, 0)),
                                encode(PlanMsg(args.target, k, k * scenario.sample_time,
                                               time.time(), np.repeat(x[target][None, :],
                                                                      scenario.horizon + 1, 0),
                                               np.zeros((scenario.horizon, 2))))]
                put(payloads[0], f"{own}/cmd")
                put(payloads[1], f"{own}/plan")
                for rid in ids:
                    if rid != args.target:
                        put(payloads[1], f"{own}/plan/{rid}")
                sent["flood"] += 2 + len(ids) - 1
                flooded += sum(map(len, payloads)) + (len(ids) - 1) * len(payloads[1])
            if "settings" in attacks and not sent["settings"] and last is not None \
                    and last.sample >= args.at and last.sample + args.sample_offset >= 0:
                detail = {"process": f"robot/{args.target}", "collision_margin": "0.5"}
                put(encode(CmdMsg(args.target, last.sample + args.sample_offset,
                                  np.array([forged_speed(upper), 0.0]), 0.0,
                                  "settings-mismatch", 0, None, "0123456789abcdef", detail)),
                    f"robot/{args.target}/cmd", block=True)
                sent["settings"] += 1
            if (len(seen), links, done_sent) != reported:  # what it learned, as it goes
                reported = (len(seen), links, done_sent)
                report()
    finally:
        # reported first: an undeclare or close that hangs (zenoh-python #434) loses nothing
        report()
        for obj in (states, token, plan_sub):
            if obj is not None:
                obj.undeclare()
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
