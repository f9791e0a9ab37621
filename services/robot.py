# ruff: noqa: E402
"""One robot's decentralized controller as a service.

``python -m services.robot --id J --scenario S [--decentralized-mode shared|paper]
[--settings FILE.toml] [controller options as sqpmpc run] [--run R] [--connect EP]
[--listen EP] [--timeout S]`` (also ``sqpmpc robot ...``)

At sample ``k`` the robot waits for the plant's states of sample ``k`` and
for the plan its shared row with each neighbour is built from (of sample
:func:`sqpmpc.control.plans.pair_sample`: ``k - 1``, or older when plans have
been late, from the ``plan_ages`` the plant relays with the states) of every
neighbour whose liveliness token is present and was present at its step
``k - 1`` (up to ``--timeout`` in lockstep, a fifth of the plant's budget in
real time), then calls :class:`sqpmpc.control.decentralized.DecentralizedController`
exactly as the in-process simulation does: ``plans`` holds, per neighbour, the
newest plan computed before sample ``k`` (and any older one kept, on request),
``previous_states`` the states of ``k - 1``, ``plan_ages`` the relayed
reports. A neighbour that is gone or silent is left out of ``plans``: the
controller predicts it from its states (the paper's fallback). It then
publishes its plan and its input, with its own ``plan_ages``.

Before its first step the robot waits (up to ``--timeout``) until it sees
every neighbour's token: in peer mode that proves a direct link, over which
the neighbour's subscriptions were declared before its token, so no plan of
the lockstep loop can be lost and the run is deterministic.
"""

from __future__ import annotations

if __name__ == "__main__":  # before the slow imports: a stop during them is honoured
    from services.early import catch_signals

    catch_signals()

import argparse
import logging
import sys
import threading
import time
from contextlib import AbstractContextManager, nullcontext

import numpy as np
import zenoh

from sqpmpc.cli.options import Parser, combination_problem
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.plans import pair_sample
from sqpmpc.errors import ProblemError
from sqpmpc.problem.scenario import Scenario

from .control import (
    ControllerNode,
    SampleStates,
    add_controller_arguments,
    controller_settings,
)
from .messages import Message, PlanMsg, encode
from .node import (
    POLL,
    add_common_arguments,
    fail,
    install_signal_handlers,
    open_node,
    options_of,
    scenario_from_args,
    session_lost,
    setup_logging,
)
from .plans import PlanStore, StepPlans, slotted
from .ros2.options import add_ros2_arguments, ros2_problem
from .ros2.robot import main_ros2

__all__ = ["RobotNode", "build_parser", "credentials_problem", "host", "main"]

log = logging.getLogger(__name__)
PROG = "services.robot"


class RobotNode(ControllerNode):
    """The service of robot ``robot_id``.

    Parameters
    ----------
    scenario
        The problem.
    args
        Parsed arguments (see :func:`build_parser`).
    robot_id
        The robot (default ``args.id``, or its only element).
    """

    def __init__(self, scenario: Scenario, args: argparse.Namespace,
                 robot_id: int | None = None) -> None:
        if robot_id is None:
            robot_id = args.id[0] if isinstance(args.id, list) else args.id
        settings = controller_settings(args, scenario)
        options = options_of(args)
        self.controller = DecentralizedController(scenario, robot_id, settings,
                                                  options.decentralized_mode)
        super().__init__(scenario, args, f"robot/{robot_id}", "decentralized")
        self.robot_id = int(robot_id)
        self.neighbours = [i for i in self.ids if i != self.robot_id]
        # with neighbour slots, a robot receives the plans of the robots that may take one
        # of its slots (they address them to it) and decodes a plan when a step reads it
        self.filtering = (self.controller.settings.neighbour_slots is not None
                          and not options.all_plans)  # the settings as resolved for this scenario
        self.plans = PlanStore(self.validator, self.neighbours, self.policy,
                               lambda: self.cursor.sample, lazy=self.filtering,
                               truth=self.true_state)
        self.addressed = 0  # plans sent on robot/<id>/plan/<to>
        self.step_lock: AbstractContextManager[object] = nullcontext()
        self.fallback_samples = 0
        self.joined = False
        self.waited_for: set[int] = set()  # neighbours alive at this robot's previous step
        # lockstep: neighbours alive but silent (no plan within --timeout), by the sample of
        # the plan that did not come; not waited for until a plan of it or later does
        self.silent: dict[int, int] = {}

    def true_state(self, robot_id: int, sample: int) -> np.ndarray | None:
        """The plant's state of robot ``robot_id`` at ``sample``, if this robot has it (a
        neighbour's plan of that sample must start there: :class:`services.plans.PlanStore`)."""
        entry = self.samples.get(sample)
        if entry is None or robot_id not in self.ids:
            return None
        return entry.states[self.ids.index(robot_id)]

    def take_plan(self, robot_id: int, payload: bytes) -> bool:
        if robot_id not in self.plans:
            return False
        self.plans.add(robot_id, payload)
        return True

    def on_other(self, kind: str, msg: Message) -> None:
        if isinstance(msg, PlanMsg) and msg.id in self.plans:
            self.plans.add_decoded(msg)

    def on_liveliness(self, name: str, alive: bool) -> None:
        super().on_liveliness(name, alive)
        if not alive and name.startswith("robot/"):
            try:
                rid = int(name.split("/", 1)[1])
            except ValueError:
                return
            if rid in self.plans:  # gone: an obstacle from now on
                self.plans.clear(rid)

    def _alive_neighbours(self) -> list[int]:
        return [i for i in self.neighbours if f"robot/{i}" in self.alive]

    def subscriptions(self) -> list[tuple[object, ...]]:
        """The keys this robot listens to: the plant's, and its neighbours' plans (those
        addressed to it when filtering)."""
        plans: list[tuple[object, ...]] = (
            [("robot", "*", "plan", self.robot_id)] if self.filtering
            else [("robot", i, "plan") for i in self.neighbours])
        return [("plant", "state"), ("plant", "done"), *plans]

    def needed(self, states: np.ndarray) -> list[int]:
        """Neighbours whose plans the step at ``states`` reads.

        With neighbour slots: those the controller gives a slot
        (:func:`~services.plans.slotted`); without: every neighbour.
        """
        if not self.filtering:
            return self.neighbours
        return slotted(states, self.controller)

    def plans_for(self, sample: int, states: np.ndarray | None = None) -> StepPlans:
        """Per alive neighbour (those given a slot at ``states`` when filtering), the
        newest plan computed before ``sample``, decoded when read."""
        alive = self._alive_neighbours()
        if states is not None and self.filtering:
            near = set(self.needed(states))
            alive = [i for i in alive if i in near]
        return StepPlans(self.plans, sample, alive)

    def publish_plan(self, msg: PlanMsg, states: np.ndarray) -> None:
        """Publish this robot's plan on its key and, when filtering, to every robot that
        may give it a slot at the next sample (the controller's
        :meth:`~sqpmpc.control.neighbours.NeighbourSelector.recipients`)."""
        payload = encode(msg)
        self.sent(payload, "robot", self.robot_id, "plan")
        if self.filtering:
            for j in self.controller.selector.recipients(states):
                self.sent(payload, "robot", self.robot_id, "plan", int(self.ids[j]))
                self.addressed += 1

    def run(self) -> int:
        status = super().run()
        log.info("robot %d: %d plans received, %d decoded, %d sent addressed", self.robot_id,
                 self.plans.received, self.plans.decoded, self.addressed)
        log.info("robot %d: plans in order per sender (sender:count@newest sample): %s",
                 self.robot_id, " ".join(f"{j}:{n}@{s}"
                                         for j, (n, s) in sorted(self.plans.in_order.items())))
        for rid, n in sorted(self.plans.false.items()):
            log.warning("robot %d: untrusted robot %d: %d false plans refused", self.robot_id,
                        rid, n)
        return status

    def step_sample(self, sample: int, entry: SampleStates) -> None:
        if not self.joined:
            # every neighbour's token seen means a direct link to it (and its
            # subscriptions) exists: from here on no plan can be lost
            self.joined = True
            if not self.wait_until(lambda: len(self._alive_neighbours()) == len(self.neighbours),
                                   self.timeout):
                missing = sorted(set(self.neighbours) - set(self._alive_neighbours()))
                log.warning("robot %d starts without neighbours %s", self.robot_id, missing)
        needed = self.needed(entry.states)
        # wait for the plan of the pair's sample (k - 1 unless plans were late) of every
        # neighbour within reach that was there at this robot's step k - 1 (one that joined
        # since then has none; at the first step: none)
        for i in [i for i, s in self.silent.items() if self.plans.has(i, s)]:
            del self.silent[i]
            log.info("robot %d sample %d: robot %d sends plans again", self.robot_id, sample, i)
        if sample > 0 and self.waited_for:
            pending = [i for i in needed if i in self.waited_for and i not in self.silent]
            wanted = {i: pair_sample(sample, self.robot_id, i, entry.plan_ages)
                      for i in pending}

            def ready() -> bool:  # O(1) per event: drop the satisfied from the end
                if self.pending is not None:  # another state came: this one is obsolete
                    return True
                while pending and (self.plans.has(pending[-1], wanted[pending[-1]])
                                   or f"robot/{pending[-1]}" not in self.alive):
                    pending.pop()
                return not pending

            wait = self.timeout if entry.budget is None else min(self.timeout,
                                                                  0.2 * entry.budget)
            if not self.wait_until(ready, wait) and not self.stop.is_set():
                log.warning("robot %d sample %d: no plan of sample %s from %s in %.3g s%s",
                            self.robot_id, sample, sorted({wanted[i] for i in pending}),
                            pending, wait, "" if entry.budget is not None else
                            ": predicted from its states, not waited for until it sends again")
                if entry.budget is None:  # lockstep: there but silent, not waited for again
                    self.silent.update((i, wanted[i]) for i in pending)
        self.waited_for = set(self._alive_neighbours())
        plans = self.plans_for(sample, entry.states)
        if len(plans) < len(needed):
            self.fallback_samples += 1
        with self.step_lock:  # one step at a time in a process hosting several robots
            # the robots whose controllers left for good, as the plant says (every
            # controller at the same sample)
            self.controller.update_departed([i for i in entry.gone if i != self.robot_id])
            out = self.controller.step(sample, entry.t, entry.measured, plans,
                                       self.previous_states(sample), entry.plan_ages)
        plan = self.controller.published
        self.publish_plan(PlanMsg(self.robot_id, sample, entry.t, time.time(), plan.states,
                                  plan.inputs), entry.states)
        self.publish_cmd(self.robot_id, sample, out.inputs[0], out.compute_time, out.fallback,
                         self.controller.plan_ages)
        self.plans.prune(sample - self.scenario.horizon - 1)  # keep what a later sample may use
        if out.fallback is not None:
            log.debug("robot %d sample %d: fallback %s", self.robot_id, sample, out.fallback)


def host(nodes: list[RobotNode]) -> int:
    """Serve several robots in this process, one thread and one Zenoh session each.

    The signal handlers are installed once and set every node's ``stop``; a
    node whose loop ends (or fails) closes its session at once, so the others
    see it go as they would see a process exit. The controllers' steps take
    turns (one lock): a step is not sliced with the others' by the GIL, so its
    measured compute time and the QP time limit mean the same as in a process
    of its own. Returns 0 when every node returned 0, else 1.
    """
    stop = threading.Event()
    signals = install_signal_handlers(stop)
    step_lock = threading.Lock()
    for node in nodes:
        node.stop, node.signals, node.step_lock = stop, signals, step_lock
        node.start(node.subscriptions(), signals=False)
    status = dict.fromkeys(range(len(nodes)), 1)

    def serve(j: int) -> None:
        try:
            status[j] = nodes[j].run()
        except Exception:
            log.exception("%s failed", nodes[j].name)
        finally:
            nodes[j].close()

    threads = [threading.Thread(target=serve, args=(j,), name=node.name, daemon=True)
               for j, node in enumerate(nodes)]
    for t in threads:
        t.start()
    for t in threads:
        while t.is_alive():
            t.join(POLL)  # the main thread stays free to run the signal handlers
    return 0 if all(v == 0 for v in status.values()) else 1


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.robot`` (``sqpmpc robot``)."""
    parser = Parser(prog=prog, description=__doc__.splitlines()[0])
    parser.add_argument("--id", type=int, required=True, action="append",
                        help="robot id in the scenario; repeated: host several robots in this "
                             "process (one thread and one Zenoh session each, every session "
                             "listening on a free loopback port)")
    add_common_arguments(parser)
    parser.add_argument("--insecure", action="store_true",
                        help="run the plan exchange without credentials, on plain TCP (any "
                             "process that reaches the endpoints can then publish plans and "
                             "inputs as this robot); without it, a robot given no "
                             "--credentials, --credentials-fd or --zenoh-config refuses to "
                             "start")
    add_controller_arguments(parser, "longest wait for a neighbour's plan in lockstep, s")
    add_ros2_arguments(parser)
    return parser


def credentials_problem(args: argparse.Namespace) -> str | None:
    """Why the plan exchange may not start as asked, if so: secure by default, a robot
    needs ``--credentials``, ``--credentials-fd`` or ``--zenoh-config``, or ``--insecure``
    explicitly (not both)."""
    given = [flag for flag, value in (("--credentials", args.credentials),
                                      ("--credentials-fd", args.credentials_fd),
                                      ("--zenoh-config", args.zenoh_config))
             if value is not None]
    if args.insecure and given:
        return f"give {given[0]} or --insecure, not both"
    if not args.insecure and not given:
        return ("no credentials: the plan exchange needs --credentials DIR (sqpmpc "
                "credentials), --credentials-fd FD (sqpmpc launch) or --zenoh-config FILE; "
                "--insecure runs it on plain TCP without them (debugging only)")
    return None


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit status."""
    args = build_parser(prog).parse_args(argv)
    ids = list(dict.fromkeys(args.id))
    setup_logging(args.log_level, "robot/" + ",".join(str(i) for i in ids))
    scenario = scenario_from_args(prog, args)
    try:
        for rid in ids:
            scenario.index_of(rid)
    except ProblemError as exc:
        fail(prog, f"--id: {exc}")
    problem = combination_problem(options_of(args), "decentralized", scenario.n_robots)
    if problem:
        fail(prog, problem)
    if args.ros2:  # its own options first: one error for the first thing wrong
        problem = ros2_problem(args, scenario)
        if problem:
            fail(prog, problem)
    problem = credentials_problem(args)
    if problem:
        fail(prog, problem)
    # with --insecure, the node logs INSECURE once its session is open (services.node)
    if args.ros2:  # a ROS 2 robot on its own clock, no plant (services.ros2.robot)
        return main_ros2(args, scenario, prog)
    if len(ids) > 1 and args.listen:
        fail(prog, "--listen takes one robot: with several --id every session listens on a "
                   "free loopback port")
    nodes: list[RobotNode] = []
    try:
        for rid in ids:
            nodes.append(open_node(prog, lambda rid=rid: RobotNode(scenario, args, rid)))
        if len(nodes) == 1:
            nodes[0].start(nodes[0].subscriptions())
            return nodes[0].run()
        return host(nodes)
    except zenoh.ZError as exc:
        return session_lost(prog, exc)
    finally:
        for node in nodes:
            node.close()


if __name__ == "__main__":
    sys.exit(main())
