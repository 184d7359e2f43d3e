"""A WebSocket relay that lets Foxglove clients of either protocol generation reach the live view.

foxglove-sdk's server accepts only the subprotocol ``foxglove.sdk.v1``, and answers a client offering
``foxglove.websocket.v1`` with HTTP 400. That is the subprotocol Lichtblick, older Foxglove releases and Foxglove's
own reference client (npm ``@foxglove/ws-protocol``) send. Both name the same Foxglove WebSocket protocol: the same
JSON ops (``serverInfo``, ``advertise``, ``subscribe`` ...) and the same binary message frames. A v1 client ignores
the ops it does not know.

The relay listens on the public port and accepts either subprotocol, preferring ``foxglove.sdk.v1``. For each client
it opens one connection to the SDK server on loopback, as ``foxglove.sdk.v1``, and copies every frame both ways
unchanged, text as text and binary as binary, until either side closes.
"""

from __future__ import annotations

import asyncio
import threading
from typing import Any

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
UPSTREAM_SUBPROTOCOL = "foxglove.sdk.v1"


class SubprotocolRelay:
    """Serve ``host:port`` (0: any free port, then ``self.port``), relaying every client to the Foxglove server on
    ``127.0.0.1:upstream_port``. Runs its own event loop in a daemon thread; ``close()`` stops it."""

    def __init__(self, host: str, port: int, upstream_port: int):
        self.upstream = f"ws://127.0.0.1:{upstream_port}"
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._server: Any = None
        self._thread = threading.Thread(target=self._run, args=(host, port), name="foxglove-relay", daemon=True)
        self._thread.start()
        self._ready.wait(30)
        if self._error is not None:
            raise self._error
        if self._server is None:
            raise TimeoutError(f"the Foxglove relay did not start on {host}:{port}")
        self.port = int(next(iter(self._server.sockets)).getsockname()[1])

    def _run(self, host: str, port: int) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._server = self._loop.run_until_complete(self._start(host, port))
        except BaseException as exc:  # noqa: BLE001 - handed to the constructor (a taken port, say)
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        self._loop.run_forever()

    async def _start(self, host: str, port: int) -> Any:
        from websockets.asyncio.server import serve

        def choose(connection: Any, offered: list[str]) -> str | None:
            for proto in SUBPROTOCOLS:
                if proto in offered:
                    return proto
            return None  # no Foxglove subprotocol offered: websockets refuses the handshake

        return await serve(self._relay, host, port, subprotocols=list(SUBPROTOCOLS), select_subprotocol=choose,
                           max_size=None, compression=None)

    async def _relay(self, client: Any) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import ConnectionClosed

        async with connect(self.upstream, subprotocols=[UPSTREAM_SUBPROTOCOL], max_size=None,
                           compression=None) as server:

            async def pump(src: Any, dst: Any) -> None:
                try:
                    async for frame in src:
                        await dst.send(frame)
                except ConnectionClosed:
                    pass

            tasks = [asyncio.ensure_future(pump(client, server)), asyncio.ensure_future(pump(server, client))]
            _, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            for t in pending:
                t.cancel()

    def close(self) -> None:
        async def stop() -> None:
            self._server.close()
            await self._server.wait_closed()

        if self._server is not None and self._loop.is_running():
            asyncio.run_coroutine_threadsafe(stop(), self._loop).result(10)
            self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
