"""One robot's decentralized controller as a service.

``python -m services.robot --id J --scenario S [--mode shared|paper] [--run R]
[--connect EP] [--listen EP] [--timeout S]``

At sample ``k`` the robot waits for the plant's states of sample ``k`` and
for the plan of sample ``k - 1`` of every neighbour whose liveliness token is
present and was present at its step ``k - 1`` (up to ``--timeout`` in
lockstep, a fifth of the plant's budget in real time), then calls
:class:`sqpmpc.controllers.DecentralizedController` exactly as the in-process
simulation does: ``plans`` holds, per neighbour, the newest plan computed
before sample ``k``, ``previous_states`` the states of ``k - 1``. A neighbour
that is gone or silent is left out of ``plans``: the controller predicts it
from its states (the paper's fallback). It then publishes its plan and its
input.

Before its first step the robot waits (up to ``--timeout``) until it sees
every neighbour's token: in peer mode that proves a direct link, over which
the neighbour's subscriptions were declared before its token, so no plan of
the lockstep loop can be lost and the run is deterministic.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time

from sqpmpc.controllers import DecentralizedController, PlanMessage
from sqpmpc.errors import ProblemError
from sqpmpc.scenario import Scenario

from .control import (
    ControllerNode,
    SampleStates,
    add_controller_arguments,
    controller_settings,
)
from .messages import Message, PlanMsg, encode
from .node import add_common_arguments, fail, open_node, scenario_from_args, setup_logging

__all__ = ["RobotNode", "build_parser", "main"]

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
    """

    def __init__(self, scenario: Scenario, args: argparse.Namespace) -> None:
        self.controller = DecentralizedController(scenario, args.id, controller_settings(args),
                                                  args.mode)
        super().__init__(scenario, args, f"robot/{args.id}")
        self.robot_id = int(args.id)
        self.neighbours = [i for i in self.ids if i != self.robot_id]
        self.plans: dict[int, dict[int, PlanMessage]] = {i: {} for i in self.neighbours}
        self.fallback_samples = 0
        self.joined = False
        self.waited_for: set[int] = set()  # neighbours alive at this robot's previous step

    def on_other(self, kind: str, msg: Message) -> None:
        if isinstance(msg, PlanMsg) and msg.id != self.robot_id:
            self.plans[msg.id][msg.sample] = PlanMessage(msg.id, msg.sample, msg.states,
                                                         msg.inputs)

    def on_liveliness(self, name: str, alive: bool) -> None:
        super().on_liveliness(name, alive)
        if not alive and name.startswith("robot/"):
            try:
                rid = int(name.split("/", 1)[1])
            except ValueError:
                return
            if rid in self.plans:  # gone: an obstacle from now on
                self.plans[rid].clear()

    def _alive_neighbours(self) -> list[int]:
        return [i for i in self.neighbours if f"robot/{i}" in self.alive]

    def _has_plan(self, rid: int, sample: int) -> bool:
        return any(s >= sample for s in self.plans[rid])

    def plans_for(self, sample: int) -> dict[int, PlanMessage]:
        """Per alive neighbour, the newest plan computed before ``sample``."""
        chosen: dict[int, PlanMessage] = {}
        for rid in self._alive_neighbours():
            older = [s for s in self.plans[rid] if s < sample]
            if older:
                chosen[rid] = self.plans[rid][max(older)]
        return chosen

    def step_sample(self, sample: int, entry: SampleStates) -> None:
        if not self.joined:
            # every neighbour's token seen means a direct link to it (and its
            # subscriptions) exists: from here on no plan can be lost
            self.joined = True
            if not self.wait_until(lambda: len(self._alive_neighbours()) == len(self.neighbours),
                                   self.timeout):
                missing = sorted(set(self.neighbours) - set(self._alive_neighbours()))
                log.warning("robot %d starts without neighbours %s", self.robot_id, missing)
        # wait for the plan of k - 1 of every neighbour that was there at this robot's
        # step k - 1 (one that joined since then has none; at the first step: none)
        def expected() -> list[int]:
            return [i for i in self._alive_neighbours() if i in self.waited_for]

        if sample > 0 and self.waited_for:
            wait = self.timeout if entry.budget is None else min(self.timeout,
                                                                  0.2 * entry.budget)
            ok = self.wait_until(lambda: all(self._has_plan(i, sample - 1)
                                             for i in expected()), wait)
            if not ok and not self.stop.is_set():
                late = [i for i in expected() if not self._has_plan(i, sample - 1)]
                log.warning("robot %d sample %d: no plan of sample %d from %s in %.3g s",
                            self.robot_id, sample, sample - 1, late, wait)
        self.waited_for = set(self._alive_neighbours())
        plans = self.plans_for(sample)
        if len(plans) < len(self.neighbours):
            self.fallback_samples += 1
        out = self.controller.step(sample, entry.t, entry.states, plans,
                                   self.previous_states(sample))
        plan = self.controller.published
        self.bus.put(encode(PlanMsg(self.robot_id, sample, entry.t, time.time(), plan.states,
                                    plan.inputs)), "robot", self.robot_id, "plan")
        self.publish_cmd(self.robot_id, sample, out.inputs[0], out.compute_time, out.fallback)
        for stored in self.plans.values():  # keep what a later sample may still use
            for s in [s for s in stored if s < sample - self.scenario.horizon - 1]:
                del stored[s]
        if out.fallback is not None:
            log.debug("robot %d sample %d: fallback %s", self.robot_id, sample, out.fallback)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.robot``."""
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument("--id", type=int, required=True, help="robot id in the scenario")
    parser.add_argument("--mode", choices=("shared", "paper"), default="shared",
                        help="decentralized mode of the controller (default shared)")
    add_common_arguments(parser)
    add_controller_arguments(parser, "longest wait for a neighbour's plan in lockstep, s")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    args = build_parser().parse_args(argv)
    setup_logging(args.log_level, f"robot/{args.id}")
    scenario = scenario_from_args(PROG, args)
    try:
        scenario.index_of(args.id)
    except ProblemError as exc:
        fail(PROG, str(exc))
    node = open_node(PROG, lambda: RobotNode(scenario, args))
    try:
        node.start([("plant", "state"), ("plant", "done"),
                    *[("robot", i, "plan") for i in node.neighbours]])
        return node.run()
    finally:
        node.close()


if __name__ == "__main__":
    sys.exit(main())
