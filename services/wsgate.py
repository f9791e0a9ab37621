"""The live view's front door: both Foxglove subprotocols, the run's token, known origins.

foxglove-sdk's WebSocket server (0.30) speaks only the subprotocol
``foxglove.sdk.v1`` and admits any local client. :class:`WebSocketGate` stands
in front of it: it accepts ``foxglove.sdk.v1`` and ``foxglove.websocket.v1``
(the Foxglove WebSocket protocol's v1, spoken by ``@foxglove/ws-protocol``'s
client, Lichtblick and older Foxglove versions; the messages are the same),
refuses a client without the run's token (HTTP 401) or from a browser page of
another origin (HTTP 403), and relays every frame both ways to the SDK's
server, which listens on a loopback port of its own.

The token is given in the URL's query, ``ws://HOST:PORT/?token=TOKEN`` (what
Foxglove's *Open connection* -> *Foxglove WebSocket* takes as is), or as a
header ``Authorization: Bearer TOKEN``. A browser sends its page's origin with
the handshake; a client without one (a program, not a web page) is checked by
the token alone.
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import threading
from collections.abc import Iterable
from http import HTTPStatus
from typing import Any
from urllib.parse import parse_qs, urlsplit

from websockets.asyncio.client import connect
from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

__all__ = ["DEFAULT_ORIGINS", "SUBPROTOCOLS", "WebSocketGate"]

log = logging.getLogger(__name__)

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
"""The subprotocols the gate accepts (the SDK's own first)."""
UPSTREAM = "foxglove.sdk.v1"
"""The subprotocol of foxglove-sdk's server behind the gate."""
DEFAULT_ORIGINS = ("https://app.foxglove.dev", "https://studio.foxglove.dev", "file://")
"""Browser origins admitted by default: Foxglove's web app and a desktop app's pages."""


def _token_of(request: Request) -> str | None:
    """The token of a handshake: ``?token=`` in the path, or ``Authorization: Bearer``."""
    values = parse_qs(urlsplit(request.path).query).get("token")
    if values:
        return values[0]
    auth = request.headers.get("Authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    return None


class WebSocketGate:
    """A WebSocket server in a thread of its own that admits the run's clients and relays
    them to a local upstream server.

    Parameters
    ----------
    host, port
        Where to listen (``port`` 0: any free port, see :attr:`port`).
    upstream_port
        The port of foxglove-sdk's server on 127.0.0.1.
    token
        The secret a client must present.
    origins
        Browser origins admitted (``"*"`` among them: any); a client without an
        ``Origin`` header is always admitted by origin.

    Raises
    ------
    OSError
        The address cannot be bound.
    """

    def __init__(self, host: str, port: int, upstream_port: int, token: str,
                 origins: Iterable[str] = DEFAULT_ORIGINS) -> None:
        self.host = host
        self.upstream = f"ws://127.0.0.1:{int(upstream_port)}"
        self._token = token.encode()
        self.origins = {o.rstrip("/") for o in origins}
        self.refused = {"token": 0, "origin": 0}
        self.admitted = 0
        self._loop = asyncio.new_event_loop()
        self._server: Server | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(host, int(port)),
                                        name="ws-gate", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self._error is not None:
            raise self._error

    @property
    def port(self) -> int:
        """The port the gate listens on."""
        if self._server is None:
            raise RuntimeError("the WebSocket gate is not serving")
        return int(self._server.sockets[0].getsockname()[1])

    def _run(self, host: str, port: int) -> None:
        asyncio.set_event_loop(self._loop)
        async def start() -> Server:
            return await serve(self._relay, host, port, subprotocols=list(SUBPROTOCOLS),
                               process_request=self._check, compression=None, max_size=None,
                               max_queue=None, server_header="sqpmpc viewer")

        try:
            self._server = self._loop.run_until_complete(start())
        except BaseException as exc:  # reported to the constructor's caller
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        self._loop.run_forever()

    def _check(self, connection: ServerConnection, request: Request) -> Response | None:
        """Refuse a handshake without the token (401) or from a foreign origin (403)."""
        origin = request.headers.get("Origin")
        if origin is not None and "*" not in self.origins and origin.rstrip("/") not in \
                self.origins:
            self.refused["origin"] += 1
            log.warning("refused a client from origin %s (allowed: %s; --allow-origin adds "
                        "one)", origin, ", ".join(sorted(self.origins)))
            return connection.respond(HTTPStatus.FORBIDDEN,
                                      f"origin {origin} is not allowed\n")
        given = _token_of(request)
        if given is None or not hmac.compare_digest(given.encode(), self._token):
            self.refused["token"] += 1
            log.warning("refused a client %s the run's token",
                        "without" if given is None else "with a wrong")
            return connection.respond(HTTPStatus.UNAUTHORIZED,
                                      "this live view needs the run's token: "
                                      "ws://HOST:PORT/?token=TOKEN\n")
        return None

    async def _relay(self, client: ServerConnection) -> None:
        """Relay one admitted client's frames to and from the upstream server."""
        self.admitted += 1
        log.info("client %s admitted (%s)", client.remote_address, client.subprotocol)
        try:
            async with connect(self.upstream, subprotocols=[UPSTREAM], compression=None,
                               max_size=None, max_queue=None) as upstream:

                async def pump(source: Any, sink: Any) -> None:
                    try:
                        async for frame in source:
                            await sink.send(frame)
                    except ConnectionClosed:
                        pass

                tasks = [asyncio.ensure_future(pump(client, upstream)),
                         asyncio.ensure_future(pump(upstream, client))]
                await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
                for task in tasks:
                    task.cancel()
        except (OSError, ConnectionClosed) as exc:
            log.warning("relay of %s ended: %s", client.remote_address, exc)

    def stop(self) -> None:
        """Close every connection and the server, end the thread."""
        if self._server is None or not self._thread.is_alive():
            return

        server = self._server

        async def close() -> None:
            server.close()
            await server.wait_closed()

        try:
            asyncio.run_coroutine_threadsafe(close(), self._loop).result(timeout=10)
        except (TimeoutError, RuntimeError) as exc:
            log.warning("the WebSocket gate did not close cleanly: %s", exc)
        finally:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=10)
