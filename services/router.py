"""A Zenoh router in Python (the same wheel as the services: no version skew).

``python -m services.router [--listen tcp/0.0.0.0:7447] [--connect EP]``

It opens a session in ``router`` mode with multicast scouting off and routes
until SIGINT or SIGTERM, then closes the session. ``zenohd`` is not on PyPI;
this lets docker-compose and the tests use one image and one interpreter.
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading

import zenoh

from .node import install_signal_handlers, setup_logging
from .transport import make_config

__all__ = ["build_parser", "main"]

log = logging.getLogger("services.router")
PROG = "services.router"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.router``."""
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument("--listen", action="append", default=[], metavar="EP",
                        help="endpoint to listen on (repeatable; default tcp/0.0.0.0:7447)")
    parser.add_argument("--connect", action="append", default=[], metavar="EP",
                        help="another router to connect to (repeatable)")
    parser.add_argument("--log-level", default="INFO")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    args = build_parser().parse_args(argv)
    setup_logging(args.log_level, "router")
    listen = args.listen or ["tcp/0.0.0.0:7447"]
    try:
        conf = make_config(listen, args.connect, "router")
        session = zenoh.open(conf)
    except (ValueError, zenoh.ZError) as exc:
        print(f"{PROG}: error: cannot start the router on {listen}: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    received = install_signal_handlers(stop)
    log.info("routing on %s", ", ".join(listen))
    try:
        while not stop.wait(0.5):
            pass
        log.info("stopping on signal %s", received.get("signal"))
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
