"""A TCP relay that delays every byte, and the probes that measure a link.

``python -m services.relay relay --delay S --route LISTEN=TARGET [--route ...]``
listens on each ``LISTEN`` (``HOST:PORT``) and forwards every connection to
its ``TARGET``, holding the bytes of each direction ``S`` seconds before
passing them on (in order; a connection's close is passed on after its
last bytes). It is the delay of a link where the kernel has none to offer
(no ``sch_netem``): a Zenoh link through it sees ``S`` more one-way latency
each way. Unlike a delaying link it terminates TCP on both sides: a packet
lost on either side is resent by that side's TCP, which then adds its own
retransmission delay to the relay's.

``python -m services.relay echo --tcp HOST:PORT [--udp HOST:PORT]`` answers
every TCP byte and UDP datagram with itself; ``python -m services.relay probe
--tcp HOST:PORT --udp HOST:PORT [--count K]`` measures through them: the
share of UDP datagrams that did not come back, and the round-trip times of
small TCP messages (a JSON line on stdout). Each runs until SIGINT/SIGTERM
(the probe until done).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import signal
import socket
import statistics
import sys
import time
from collections.abc import Sequence

from sqpmpc.cli.options import Parser, nonnegative_float, positive_float

__all__ = ["build_parser", "main", "parse_address", "probe", "relay"]

PROG = "services.relay"
CHUNK = 65536
TARGET_TRIES = 50
"""Attempts (0.1 s apart) to reach a route's target for a new connection."""


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` -> ``(host, port)``; :class:`ValueError` naming the text if not."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"expected HOST:PORT, got {text!r}")
    return host, int(port)


async def _pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                delay: float) -> None:
    """Copy ``reader`` to ``writer``, each chunk ``delay`` s after it was read."""
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue()

    async def feed() -> None:
        try:
            while data := await reader.read(CHUNK):
                queue.put_nowait((loop.time() + delay, data))
        except (ConnectionError, OSError):
            pass
        queue.put_nowait((loop.time() + delay, b""))

    feeder = asyncio.create_task(feed())
    try:
        while True:
            due, data = await queue.get()
            wait = due - loop.time()
            if wait > 0:
                await asyncio.sleep(wait)
            if not data:
                if writer.can_write_eof():
                    writer.write_eof()
                break
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError):
        pass
    finally:
        feeder.cancel()


async def relay(routes: Sequence[tuple[tuple[str, int], tuple[str, int]]], delay: float,
                stop: asyncio.Event) -> None:
    """Serve every ``(listen, target)`` route with ``delay`` s each way until ``stop``."""

    def handler(target: tuple[str, int]):
        async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            for attempt in range(TARGET_TRIES):  # the target may still be starting
                try:
                    up_r, up_w = await asyncio.open_connection(*target)
                    break
                except OSError:
                    if attempt == TARGET_TRIES - 1:
                        writer.close()
                        return
                    await asyncio.sleep(0.1)
            for w in (writer, up_w):
                w.get_extra_info("socket").setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY,
                                                      1)
            await asyncio.gather(_pump(reader, up_w, delay), _pump(up_r, writer, delay))
            for w in (writer, up_w):
                w.close()
        return handle

    servers = [await asyncio.start_server(handler(target), *listen, reuse_address=True)
               for listen, target in routes]
    await stop.wait()
    for s in servers:
        s.close()


async def _echo(tcp: tuple[str, int], udp: tuple[str, int] | None, stop: asyncio.Event) -> None:
    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writer.get_extra_info("socket").setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            while data := await reader.read(CHUNK):
                writer.write(data)
                await writer.drain()
        except (ConnectionError, OSError):
            pass
        writer.close()

    class Echo(asyncio.DatagramProtocol):
        def connection_made(self, transport: asyncio.BaseTransport) -> None:
            self.transport = transport

        def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
            self.transport.sendto(data, addr)

    server = await asyncio.start_server(handle, *tcp, reuse_address=True)
    transport = None
    if udp is not None:
        transport, _ = await asyncio.get_running_loop().create_datagram_endpoint(
            Echo, local_addr=udp)
    await stop.wait()
    server.close()
    if transport is not None:
        transport.close()


def _connect(address: tuple[str, int], wait: float) -> socket.socket:
    """A TCP connection to ``address``, retried while refused for up to ``wait`` s (the
    echo or relay may still be starting)."""
    deadline = time.monotonic() + wait
    while True:
        try:
            return socket.create_connection(address, timeout=30.0)
        except ConnectionRefusedError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def probe(tcp: tuple[str, int], udp: tuple[str, int] | None, count: int = 300,
          interval: float = 0.01, size: int = 64) -> dict:
    """Round trips through an echo: TCP round-trip times (s), then the share of UDP
    datagrams lost (both ways)."""
    rtts = []
    with _connect(tcp, 30.0) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for _ in range(count):
            started = time.monotonic()
            s.sendall(bytes(size))
            got = 0
            while got < size:
                data = s.recv(CHUNK)
                if not data:
                    raise ConnectionError("the echo closed the connection")
                got += len(data)
            rtts.append(time.monotonic() - started)
            time.sleep(interval)
    rtts.sort()
    out: dict = {"count": count, "tcp_rtt": {
        "min": rtts[0], "median": statistics.median(rtts),
        "p90": rtts[int(0.9 * (len(rtts) - 1))], "max": rtts[-1]}}
    if udp is not None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.settimeout(0.0)
            s.connect(udp)
            back: set[int] = set()
            for k in range(count):
                try:
                    s.send(k.to_bytes(4, "big") + bytes(size - 4))
                except PermissionError:  # a firewall rule dropped it on the way out
                    pass
                end = time.monotonic() + interval
                while time.monotonic() < end:
                    try:
                        back.add(int.from_bytes(s.recv(CHUNK)[:4], "big"))
                    except BlockingIOError:
                        time.sleep(0.001)
            end = time.monotonic() + 1.0
            while time.monotonic() < end:
                try:
                    back.add(int.from_bytes(s.recv(CHUNK)[:4], "big"))
                except BlockingIOError:
                    time.sleep(0.005)
        out["udp_round_trip_loss"] = 1.0 - len(back) / count
    return out


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.relay``."""
    p = Parser(prog=prog, description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("relay", help="forward TCP connections with a delay")
    r.add_argument("--delay", type=nonnegative_float, required=True, help="one-way delay, s")
    r.add_argument("--route", action="append", required=True, metavar="LISTEN=TARGET",
                   help="HOST:PORT=HOST:PORT (repeatable)")
    e = sub.add_parser("echo", help="echo TCP (and UDP)")
    e.add_argument("--tcp", required=True, metavar="HOST:PORT")
    e.add_argument("--udp", default=None, metavar="HOST:PORT")
    q = sub.add_parser("probe", help="measure round trips through an echo")
    q.add_argument("--tcp", required=True, metavar="HOST:PORT")
    q.add_argument("--udp", default=None, metavar="HOST:PORT")
    q.add_argument("--count", type=int, default=300)
    q.add_argument("--interval", type=positive_float, default=0.01, metavar="S")
    return p


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit status (2: bad input)."""
    args = build_parser(prog).parse_args(argv)
    try:
        if args.command == "relay":
            routes = []
            for item in args.route:
                listen, sep, target = item.partition("=")
                if not sep:
                    raise ValueError(f"--route: expected LISTEN=TARGET, got {item!r}")
                routes.append((parse_address(listen), parse_address(target)))
        elif args.command == "probe" and args.count < 1:
            raise ValueError(f"--count: expected >= 1, got {args.count}")
        tcp = parse_address(args.tcp) if args.command != "relay" else None
        udp = parse_address(args.udp) if args.command != "relay" and args.udp else None
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    if args.command == "probe":
        try:
            print(json.dumps(probe(tcp, udp, args.count, args.interval)), flush=True)
        except OSError as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return 1
        return 0

    async def serve() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        if args.command == "relay":
            await relay(routes, args.delay, stop)
        else:
            await _echo(tcp, udp, stop)

    try:
        asyncio.run(serve())
    except OSError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
