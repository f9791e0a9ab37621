# ruff: noqa: E402
"""A Zenoh router in Python (the same wheel as the services: no version skew).

``python -m services.router [--listen tcp/127.0.0.1:7447] [--connect EP]
[--credentials DIR | --zenoh-config FILE]``

It opens a session in ``router`` mode with multicast scouting off and routes
until SIGINT or SIGTERM, then closes the session. With credentials
(:mod:`services.credentials`: the ``router`` identity, or a ``zenohd`` config
such as ``router.json5`` of ``sqpmpc credentials``) it accepts mutual-TLS links only;
it enforces
the run's access-control rules on what every client sends; without, it routes
plain TCP from anyone who reaches the endpoint. ``zenohd`` is not on PyPI;
this lets docker-compose and the tests use one image and one interpreter.
"""

from __future__ import annotations

if __name__ == "__main__":  # before the slow imports: a stop during them is honoured
    from services.early import catch_signals

    catch_signals()

import argparse
import json
import logging
import sys
import threading

import zenoh

from sqpmpc import __version__
from sqpmpc.cli.options import Parser
from sqpmpc.errors import ProblemError

from .credentials import config_for
from .node import add_credential_arguments, install_signal_handlers, setup_logging
from .transport import make_config

__all__ = ["build_parser", "main"]

log = logging.getLogger("services.router")
PROG = "services.router"


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.router`` (``sqpmpc router``)."""
    parser = Parser(prog=prog, description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--listen", action="append", default=[], metavar="EP",
                        help="endpoint to listen on (repeatable; default: the config file's, "
                             "else tcp/127.0.0.1:7447)")
    parser.add_argument("--connect", action="append", default=[], metavar="EP",
                        help="another router to connect to (repeatable)")
    parser.add_argument("--log-level", default="INFO")
    add_credential_arguments(parser)
    return parser


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit status."""
    args = build_parser(prog).parse_args(argv)
    setup_logging(args.log_level, "router")
    try:
        config = config_for(args, "router")
    except ProblemError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    listen = args.listen or ([] if config is not None else ["tcp/127.0.0.1:7447"])
    try:
        conf = make_config(listen, args.connect, "router", config)
        listen = json.loads(conf.get_json("listen/endpoints"))
        session = zenoh.open(conf)
    except (ValueError, zenoh.ZError) as exc:
        print(f"{prog}: error: cannot start the router on {listen or 'its endpoints'}: "
              f"{str(exc).split(' at /')[0]}", file=sys.stderr)
        return 2
    if config is None:
        log.warning("no --credentials: unauthenticated routing for anyone who reaches %s",
                    ", ".join(listen))
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
