# ruff: noqa: E402
"""The plant service: holds the true state, publishes it, applies the controllers' inputs.

``python -m services.plant --scenario S [--scheme decentralized|centralized]
[--mode lockstep|realtime] [--out DIR] [--run R] [--connect EP] [--listen EP]
[--timeout S] [--startup-timeout S] [--t-end T] [--sample-time TS] [--horizon N]
[--settings FILE.toml] [controller options as sqpmpc run] [--no-plots]``
(also ``sqpmpc plant ...``)

The plant takes the controller options too: with the scenario they make the
settings every process of the run must share (:mod:`services.agreement`). A
controller started with others answers the plant's first state with them: the
plant logs one message naming what differs and goes on, braking that
controller's robots while it answers so (it then exits); at the end it exits
with status 2 (``refused`` in ``metrics.json``).

No message on a robot's keys can stop, stall or rewind the run. The plant
judges an input's sample before anything else: an input of an older sample
is stale and dropped whatever it carries; one of a later sample is refused.
An input of the current sample that carries another settings digest marks
its robot faulty at this sample: braked, not waited for, even if a
consistent input came too. Every input on robot ``j``'s key that is
inconsistent with the run (schema, sample ahead, settings digest) is dropped
and counted in ``faulty_messages[j]``. Every ``--status-every``
seconds (default 10) it writes a status line to stderr (sample, time, smallest
clearance so far, braked inputs).

Before sample 0 it waits (up to ``--startup-timeout``) for the liveliness of
every controller of the scheme (one may still join later). A run in which some
robot's controller never sent an input ends with one error line naming the
robots, which were braked all along, and status 3 (``never_controlled`` in
``metrics.json``). Then, at every sample ``k``, it publishes the
states of all robots (one message) and collects one ``cmd`` per robot:

- ``lockstep``: it advances as soon as every robot whose controller is alive
  has sent its input for ``k``, or after ``--timeout`` seconds; a controller
  that leaves mid-run (its liveliness token gone: killed, crashed) is waited
  for up to ``--rejoin-timeout`` seconds (default 30): restarted with its
  command, it rejoins at the sample where it left;
- ``realtime``: it advances every ``Ts`` of wall time with the newest valid
  input received for ``k``. Sample 0 is the exception: the robots are at
  rest and the controllers converge their first plan (several QPs, the
  settings' ``first_sample_iterations``), so the plant waits for its inputs as
  in lockstep and starts the wall clock after it (``--timed-start``: sample 0
  gets ``Ts`` too); ``metrics.json`` records that start as ``start_wall_s``.

When every controller has been gone for ``--rejoin-timeout`` seconds (any
mode) the plant stops with one error line (``abandoned`` in ``metrics.json``),
writes what it has and exits with status 1.

A robot without an input (late, timed out, or its controller gone) gets the
braking input (``v = omega = 0`` clipped to the bounds), counted in
``missed_deadlines``; so does a robot the sample's states message lists as ``gone``,
whatever its controller sends (the others plan with it braked). The state advances
with the scenario's ``[plant]`` model and input noise (:class:`sqpmpc.problem.plant.Plant`), as in
:class:`sqpmpc.sim.simulation.ClosedLoopSimulation`.
It also keeps the plans the controllers publish on ``robot/<id>/plan``.
With the states of ``k + 1`` it relays the ``plan_ages`` of the inputs it
applied at ``k`` (the same to every robot: both robots of a pair agree on the
plans of their shared row from it, :func:`sqpmpc.control.plans.pair_sample`).
At the end, also on SIGINT/SIGTERM (then as far as it got), it writes
``metrics.json``, ``trajectory.npz``, ``recording.mcap`` (with those plans) and the
plots into ``--out``. As it goes it appends every sample to ``--out``/``record.msgpack``
(:mod:`sqpmpc.io.runlog`, flushed every sample): after a ``kill -9`` of the plant,
``sqpmpc metrics DIR`` writes ``metrics.json`` and ``trajectory.npz`` from it.
``metrics.json``'s ``insecure`` is true when the plant ran without credentials (plain
TCP: then so did the run's plan exchange, ``sqpmpc launch --insecure``).
"""

from __future__ import annotations

if __name__ == "__main__":  # before the slow imports: a stop during them is honoured
    from services.early import catch_signals

    catch_signals()

import argparse
import logging
import signal
import sys
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from sqpmpc.cli.options import (
    Parser,
    add_controller_options,
    combination_problem,
    nonnegative_float,
    positive_float,
)
from sqpmpc.control.pipeline import braking_input
from sqpmpc.errors import ProblemError
from sqpmpc.io.files import write_plots, write_run
from sqpmpc.io.recorder import owner_hint, prepare_output
from sqpmpc.io.reporting import STATUS_PERIOD, StatusLines
from sqpmpc.io.reporting import summarize as summary_of
from sqpmpc.io.runlog import RECORD_FILE, RecordWriter
from sqpmpc.problem.plant import Plant
from sqpmpc.problem.scenario import Scenario
from sqpmpc.sim.record import RunRecord

from .messages import MAX_PLAN_AGES, CmdMsg, DoneMsg, Message, PlanMsg, StateMsg, encode
from .node import (
    Node,
    add_common_arguments,
    fail,
    open_node,
    options_of,
    scenario_from_args,
    session_lost,
    setup_logging,
)
from .presence import REJOIN_TIMEOUT, FaultyInputs, Presence
from .protocol import Verdict
from .tallies import response_ms, summed

__all__ = ["REJOIN_TIMEOUT", "PlantNode", "build_parser", "main", "summarize"]

log = logging.getLogger(__name__)
PROG = "services.plant"
RESEND = 0.05
"""Lockstep: while inputs of a sample are missing, its states are published again this
often, s (at most every half ``--timeout``; real time: every ``Ts / 4``)."""


class PlantNode(Presence, FaultyInputs, Node):
    """The plant of one distributed run.

    Parameters
    ----------
    scenario
        The problem.
    args
        Parsed arguments (see :func:`build_parser`).
    """

    def __init__(self, scenario: Scenario, args: argparse.Namespace) -> None:
        super().__init__(scenario, args, "plant", args.scheme)
        self.mode = args.mode
        self.scheme = args.scheme
        self.timeout = float(args.timeout)
        self.startup_timeout = float(args.startup_timeout)
        limits = (scenario.bounds.acceleration_lower(), scenario.bounds.acceleration_upper()) \
            if scenario.bounds.dynamic_limits else None  # CONTRACT 1c: velocities change within
        self.plant = Plant(scenario.plant, scenario.sample_time, scenario.n_robots, limits)
        self.method = scenario.plant.model
        n, steps = scenario.n_robots, scenario.steps
        self.t = scenario.sample_time * np.arange(steps + 1)
        self.states = np.zeros((steps + 1, n, 3))
        self.states[0] = scenario.initial_states()
        self.inputs = np.zeros((steps, n, 2))
        self.plant_inputs = np.zeros((steps, n, 2))
        self.solve_times = np.zeros((steps, n if self.scheme == "decentralized" else 1))
        # the plans the controllers publish, for recording.mcap (NaN: not received)
        self.horizons = np.full((steps, n, scenario.horizon + 1, 3), np.nan)
        self.brake = braking_input(scenario.bounds.input_lower(), scenario.bounds.input_upper(),
                                   (1,))[0]
        self.k = 0
        self.republished = 0
        self.cmds: dict[int, CmdMsg] = {}
        self.relay: dict[int, dict[int, int]] = {}  # plan ages sent with the current states
        self.missed = dict.fromkeys(self.ids, 0)
        self.faulty = dict.fromkeys(self.ids, 0)  # inconsistent inputs dropped, per robot
        self.faulty_now: set[int] = set()  # robots braked at this sample for such an input
        self.silent: set[int] = set()  # alive, but no input within --timeout: not waited for
        self.refusing: set[str] = set()  # controllers that sent another settings digest
        self.late_commands = 0
        self.responses: dict[int, list[float]] = {rid: [] for rid in self.ids}  # s
        self.published_at = 0.0  # when the states of the current sample went out
        self.timeouts = 0
        self._missing: set[int] = set()
        self.solver_failures = 0
        self.reported_invalid: dict[str, int] = {}
        self.reported_counts: dict[str, dict[str, int]] = {}  # each controller's counters
        self.loop_wall = 0.0
        self.start_wall = 0.0
        self.timed_start = bool(getattr(args, "timed_start", False))
        self.running = False
        self.sample_walls: list[float] = []
        self.writer: RecordWriter | None = None
        self.refused: str | None = None  # a controller runs with other settings
        self.rejoin_timeout = float(getattr(args, "rejoin_timeout", REJOIN_TIMEOUT))
        self.departed: dict[str, float] = {}  # controller -> when it left (perf_counter)
        self.gone: set[int] = set()  # robots whose controllers did not rejoin in time
        self.gone_now: set[int] = set()  # the gone of the states message of this sample
        self.all_gone_since: float | None = None
        self.gave_up: str | None = None  # every controller left for good
        self.status = StatusLines(scenario, "plant", float(getattr(args, "status_every",
                                                                   STATUS_PERIOD)))

    def open_record(self, out: Path) -> None:
        """Start the incremental record ``out/record.msgpack`` (:mod:`sqpmpc.io.runlog`)."""
        settings = {"mode": self.mode, "plant_discretization": self.method,
                    "run": self.bus.prefix.rsplit("/", 1)[-1], "timeout": self.timeout}
        self.writer = RecordWriter(out / RECORD_FILE, self.scenario, self.scheme,
                                   self.solve_times.shape[1], self.states[0], settings,
                                   self.digest)

    def on_message(self, kind: str, msg: Message) -> None:
        if isinstance(msg, PlanMsg):
            if 0 <= msg.sample < self.horizons.shape[0]:
                self.horizons[msg.sample, self.ids.index(msg.id)] = msg.states
            return
        if not isinstance(msg, CmdMsg):
            return
        decision = self.policy.cmd(self.k, msg.sample)
        if decision.verdict is Verdict.REFUSE:
            self._refused(decision.reason)
            self.faulty_message(msg.id, decision.reason)
            return
        self.spoke(msg.id)
        sender = "central" if self.scheme == "centralized" else f"robot/{msg.id}"
        self.reported_invalid[sender] = msg.invalid
        self.reported_counts[sender] = msg.counters or {}
        if decision.accepted and msg.id not in self.faulty_now:
            if self.running and msg.id not in self.cmds and (self.k > 0 or self.timed_start):
                # the states out -> this input in (sample 0 untimed: compilation, joins)
                self.responses[msg.id].append(time.perf_counter() - self.published_at)
            self.cmds[msg.id] = msg  # the newest valid input for this sample
        else:
            self.late_commands += 1

    # -------------------------------------------------------------------- loop
    def publish_states(self, k: int) -> None:
        """Publish every robot's state of sample ``k``."""
        budget = self.scenario.sample_time if self.mode == "realtime" else None
        gone = self.gone_for_good()
        self.gone_now = set(gone)  # braked at k whatever arrives (apply)
        # the measured velocities too where the plant has them, as the in-process loop
        # measures (Plant.measure): the controllers start from them, not from their commands
        msg = StateMsg(k, float(self.t[k]), tuple(self.ids), self.states[k], budget, self.digest,
                       self.settings_digest, plan_ages=self.relay, gone=gone,
                       v=self.plant.velocities.copy() if self.plant.has_velocities else None)
        self.bus.put(encode(msg), "plant", "state")

    def apply(self, k: int) -> None:
        """Apply the inputs collected for sample ``k`` and integrate to ``k + 1``."""
        for rid in self.faulty_now:
            self.cmds.pop(rid, None)  # a robot that sent an inconsistent input is braked
        for rid in self.gone_now:
            # the states message of k told every controller it left: they plan with it
            # braked (DecentralizedController's braked reach), so it is, even if its
            # controller is back (it takes part from the next message on)
            self.cmds.pop(rid, None)
        missing = set(self.ids) - set(self.cmds)
        if missing != self._missing:
            if missing - self._missing:
                log.warning("sample %d: braking robots %s (no input)", k,
                            sorted(missing - self._missing))
            if self._missing - missing:
                log.info("sample %d: inputs from robots %s again", k,
                         sorted(self._missing - missing))
            self._missing = missing
        fallback = False
        failures = self.solver_failures
        self.relay = _relayed(self.cmds[rid] for rid in self.ids if rid in self.cmds)
        for j, rid in enumerate(self.ids):
            cmd = self.cmds.get(rid)
            if cmd is None:
                self.missed[rid] += 1
                self.inputs[k, j] = self.brake
                continue
            self.inputs[k, j] = cmd.u
            if self.scheme == "decentralized":
                self.solve_times[k, j] = cmd.compute_time
                self.solver_failures += cmd.fallback is not None
            else:
                self.solve_times[k, 0] = cmd.compute_time
                fallback = fallback or cmd.fallback is not None
        self.solver_failures += fallback
        self.states[k + 1], self.plant_inputs[k] = self.plant.step(self.states[k],
                                                                   self.inputs[k])
        if self.writer is not None:
            self.writer.sample(k, self.inputs[k], self.states[k + 1], self.solve_times[k],
                               self.solver_failures - failures, sorted(missing),
                               self.plant_inputs[k] if self.plant.spec.noisy
                               or self.plant.has_velocities else None)

    def run(self) -> None:
        """Run the samples until ``t_end`` or a stop signal."""
        log.info("plant (%s, %s): waiting for %s", self.mode, self.scheme,
                 ", ".join(self.controllers))
        if not self.wait_for_controllers() and not self.stop.is_set():
            log.warning("starting without %s after %.3g s",
                        sorted(set(self.controllers) - self.alive), self.startup_timeout)
        if self.stop.is_set():
            return
        ts = self.scenario.sample_time
        self.running = True
        start = time.perf_counter()
        for k in range(self.scenario.steps):
            t0 = time.perf_counter()
            self.k, self.cmds, self.faulty_now = k, {}, set()
            self.published_at = time.perf_counter()
            self.publish_states(k)
            if self.mode == "lockstep" or (k == 0 and not self.timed_start):
                if not self.collect(k, t0 + self.timeout, min(RESEND, self.timeout / 2)) \
                        and not self.stop.is_set():
                    self.timeouts += 1
                    late = sorted(set(self.expected()) - set(self.cmds) - self.faulty_now)
                    log.warning("sample %d: no input from robots %s within %.3g s",
                                k, late, self.timeout)
                    self.went_silent(late)
                if self.mode == "realtime":  # the clock starts now: Ts for sample 1
                    self.raise_priority()
                    self.start_wall = time.perf_counter() - t0
                    start = time.perf_counter() - ts
            else:
                deadline = start + (k + 1) * ts
                self.collect(k, deadline, ts / 4.0)
                self.wait_until(lambda: self.stop.is_set(), deadline - time.perf_counter())
            if self.stop.is_set() or self.abandoned():
                break
            self.apply(k)
            self.k = k + 1
            self.sample_walls.append(time.perf_counter() - t0)
            self.status.update(k + 1, self.states[k + 1],
                               f", braked inputs {sum(self.missed.values())}")
        self.running = False
        self.loop_wall = time.perf_counter() - start
        self.drain()  # plans already received, for the recording

    def collect(self, k: int, deadline: float, resend: float) -> bool:
        """Wait until every expected input of sample ``k`` is in (``True``), a stop is asked
        or ``deadline`` (``time.perf_counter``) passes; while inputs are missing, publish
        the states of ``k`` again every ``resend`` s (a state or an input was lost: the
        controllers answer a repeated state by sending their outputs again)."""
        def ready() -> bool:
            return (all(i in self.cmds or i in self.faulty_now for i in self.expected())
                    and not self.awaited())

        while True:
            end = max(deadline, self.rejoin_deadline())  # lockstep: wait for a rejoin
            if self.wait_until(ready, min(resend, end - time.perf_counter())):
                return True
            if self.stop.is_set() or time.perf_counter() >= max(deadline,
                                                                 self.rejoin_deadline()):
                return False
            self.publish_states(k)
            self.republished += 1

    def record(self) -> RunRecord:
        """What has been run so far."""
        k = self.k
        sig = self.signals.get("signal")
        walls = np.asarray(self.sample_walls) * 1e3
        invalid = {"plant": self.validator.invalid, **self.reported_invalid}
        extra: dict[str, Any] = {
            "distributed": True,
            "mode": self.mode,
            "insecure": self.insecure,  # the run's plans without credentials (plain TCP)
            "run": self.bus.prefix.rsplit("/", 1)[-1],
            "missed_deadlines": int(sum(self.missed.values())),
            "missed_deadlines_by_robot": {str(i): int(v) for i, v in self.missed.items()},
            "faulty_messages": {str(i): int(v) for i, v in self.faulty.items()},
            "never_controlled": self.never_controlled(),
            "late_commands": int(self.late_commands),
            "lockstep_timeouts": int(self.timeouts),
            "republished_states": int(self.republished),
            "stale_messages": int(self.validator.stale),
            "invalid_messages": int(sum(invalid.values())),
            "invalid_messages_by_process": invalid,
            "counters": summed(self.reported_counts.values()),
            "interrupted": signal.Signals(sig).name if sig else None,
            "refused": self.refused,
            "abandoned": self.gave_up,
            "agreed_settings": self.agreed,
            "plant_discretization": self.method,
            "sample_loop_wall_s": float(self.loop_wall),
            "start_wall_s": float(self.start_wall),
            "response_ms": response_ms(self.responses),
            "sample_wall_ms": {
                "median": float(np.median(walls)) if walls.size else None,
                "max": float(walls.max()) if walls.size else None,
            },
        }
        return RunRecord(self.scenario, self.scheme, self.t[: k + 1].copy(),
                         self.states[: k + 1].copy(), self.inputs[:k].copy(),
                         self.solve_times[:k].copy(), int(self.solver_failures),
                         k == self.scenario.steps, extra,
                         self.plant_inputs[:k].copy() if self.plant.spec.noisy
                         or self.plant.has_velocities else None,
                         horizons=self.horizons[:k].copy())

    def finish(self) -> None:
        """Tell the controllers the run is over, and the user that the outputs come next."""
        self.bus.put(encode(DoneMsg(self.k, self.k == self.scenario.steps)), "plant", "done")
        if self.status.period > 0:
            self.status.note(f"sample {self.k}/{self.scenario.steps}: writing the outputs")


def summarize(metrics: dict[str, Any]) -> str:
    """A distributed run's summary: :func:`sqpmpc.io.reporting.summarize` (as sqpmpc run's)."""
    return summary_of(metrics)


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.plant`` (``sqpmpc plant``)."""
    parser = Parser(prog=prog, description=__doc__.splitlines()[0])
    add_common_arguments(parser)
    parser.add_argument("--scheme", choices=("decentralized", "centralized"),
                        default="decentralized", help="which controllers to expect")
    parser.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default runs/<scenario>-<scheme>-<mode>-<time>)")
    parser.add_argument("--timeout", type=positive_float, default=10.0,
                        help="lockstep: longest wait for a sample's inputs, s")
    parser.add_argument("--startup-timeout", type=positive_float, default=60.0,
                        help="longest wait for the controllers before sample 0, s")
    parser.add_argument("--rejoin-timeout", type=positive_float, default=REJOIN_TIMEOUT,
                        metavar="S",
                        help="lockstep: wait this long for a controller that left mid-run to "
                             "come back (restarted) before braking its robots; any mode: stop "
                             "when every controller has been gone this long, s (default "
                             f"{REJOIN_TIMEOUT:g})")
    parser.add_argument("--overwrite", action="store_true", help="replace a run in --out")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument("--quiet", action="store_true", help="no summary on stdout")
    parser.add_argument("--timed-start", action="store_true",
                        help="realtime: sample 0 gets Ts too (default: its inputs are waited "
                             "for as in lockstep, then the wall clock starts)")
    parser.add_argument("--status-every", type=nonnegative_float, default=STATUS_PERIOD,
                        metavar="S", help="a status line on stderr every S seconds (default "
                                          f"{STATUS_PERIOD:g}; 0: none)")
    add_controller_options(parser, all_plans=True, overrides=False)
    return parser


def check_combinations(args: argparse.Namespace, scenario: Scenario) -> str | None:
    """Why the plant's flags contradict each other or do nothing together, if so."""
    if args.timed_start and args.mode != "realtime":
        return "--timed-start applies to --mode realtime only"
    return combination_problem(options_of(args), args.scheme, scenario.n_robots)


def _relayed(cmds: Iterable[CmdMsg]) -> dict[int, dict[int, int]]:
    """The inputs' ``plan_ages`` to send with the next states, by robot, at most
    :data:`~services.messages.MAX_PLAN_AGES` entries in all (a robot left out counts as
    reporting none, which both robots of each of its pairs read alike)."""
    out: dict[int, dict[int, int]] = {}
    room = MAX_PLAN_AGES
    for cmd in cmds:
        if cmd.plan_ages and len(cmd.plan_ages) <= room:
            out[cmd.id] = dict(cmd.plan_ages)
            room -= len(cmd.plan_ages)
    return out


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit status (0 completed, 2 bad input or a controller
    with other settings, 3 completed but some robot's controller never sent an input,
    128+signal, 1 otherwise)."""
    args = build_parser(prog).parse_args(argv)
    setup_logging(args.log_level, "plant")
    scenario = scenario_from_args(prog, args)
    problem = check_combinations(args, scenario)
    if problem:
        fail(prog, problem)
    out = args.out or Path("runs") / (f"{scenario.name}-{args.scheme}-{args.mode}-"
                                      f"{time.strftime('%Y%m%d-%H%M%S')}")
    try:  # the output contract of every runner: a non-empty --out only with --overwrite
        prepare_output(out, args.overwrite)
    except ProblemError as exc:
        fail(prog, f"--out: {exc}{owner_hint(out)}")
    node = open_node(prog, lambda: PlantNode(scenario, args))
    failed = False
    try:
        node.open_record(out)
        node.start([("robot", "*", "cmd"), ("robot", "*", "plan")])
        node.run()
    except zenoh.ZError as exc:
        failed = bool(session_lost(prog, exc))
    finally:
        try:
            node.finish()
        finally:
            node.close()
        record = node.record()
        if node.writer is not None:
            node.writer.end(record.completed, record.extra)
        metrics = write_run(out, record, plots=False)
        if not args.quiet:
            print(summarize(metrics))
        if not args.no_plots:  # after the summary
            write_plots(out, record, quiet=args.quiet)
        if not args.quiet:
            print(f"wrote {out}")
    sig = node.signals.get("signal")
    if sig and record.t.size == 1:
        log.warning("stopped by %s before the first sample: the run in %s has no samples",
                    signal.Signals(sig).name, out)
    if node.refused:
        return 2
    absent = record.extra.get("never_controlled") or []
    if record.completed and absent and not failed:
        log.error("no controller ever sent an input for robots %s: they were braked for the "
                  "whole run (start their controllers with the same --run and endpoints)",
                  ", ".join(map(str, absent)))
        return 3
    if record.completed and not failed:
        return 0
    return 128 + sig if sig else 1


if __name__ == "__main__":
    sys.exit(main())

