# ruff: noqa: E402
"""The centralized controller as one service speaking the robots' protocol.

``python -m services.central --scenario S [--settings FILE.toml] [controller options as
sqpmpc run] [--run R] [--connect EP] [--listen EP]`` (also ``sqpmpc central ...``)

At every sample it waits for the plant's states of all robots, runs
:class:`sqpmpc.control.centralized.CentralizedController` and publishes one ``cmd``
per robot (on each robot's key, carrying the whole computation time and the
fallback flag), so the plant runs both schemes the same way; before them, each
robot's plan on ``robot/<id>/plan`` (for the plant's recording and the viewer).
"""

from __future__ import annotations

if __name__ == "__main__":  # before the slow imports: a stop during them is honoured
    from services.early import catch_signals

    catch_signals()

import argparse
import logging
import sys
import time

import zenoh

from sqpmpc.cli.options import Parser
from sqpmpc.control.centralized import CentralizedController
from sqpmpc.problem.scenario import Scenario

from .control import (
    ControllerNode,
    SampleStates,
    add_controller_arguments,
    controller_settings,
)
from .messages import PlanMsg, encode
from .node import (
    add_common_arguments,
    open_node,
    scenario_from_args,
    session_lost,
    setup_logging,
)

__all__ = ["CentralNode", "build_parser", "main"]

log = logging.getLogger(__name__)
PROG = "services.central"


class CentralNode(ControllerNode):
    """The centralized controller service.

    Parameters
    ----------
    scenario
        The problem.
    args
        Parsed arguments (see :func:`build_parser`).
    """

    def __init__(self, scenario: Scenario, args: argparse.Namespace) -> None:
        self.controller = CentralizedController(scenario, controller_settings(args, scenario))
        super().__init__(scenario, args, "central", "centralized")

    def step_sample(self, sample: int, entry: SampleStates) -> None:
        out = self.controller.step(entry.t, entry.measured)
        # each robot's plan first (for the plant's recording and the viewer; before the
        # inputs, so the plant has it when it advances), then the inputs
        stamp = time.time()
        for j, rid in enumerate(self.ids):
            self.bus.put(encode(PlanMsg(rid, sample, entry.t, stamp, out.predicted_states[j],
                                        out.predicted_inputs[j])), "robot", rid, "plan")
        for j, rid in enumerate(self.ids):
            self.publish_cmd(rid, sample, out.inputs[j], out.compute_time, out.fallback)
        if out.fallback is not None:
            log.debug("sample %d: fallback %s", sample, out.fallback)


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.central`` (``sqpmpc central``)."""
    parser = Parser(prog=prog, description=__doc__.splitlines()[0])
    add_common_arguments(parser)
    add_controller_arguments(parser, "unused; for symmetry, s", decentralized=False)
    return parser


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit status."""
    args = build_parser(prog).parse_args(argv)
    setup_logging(args.log_level, "central")
    scenario = scenario_from_args(prog, args)
    node = open_node(prog, lambda: CentralNode(scenario, args))
    try:
        node.start([("plant", "state"), ("plant", "done")])
        return node.run()
    except zenoh.ZError as exc:
        return session_lost(prog, exc)
    finally:
        node.close()


if __name__ == "__main__":
    sys.exit(main())
