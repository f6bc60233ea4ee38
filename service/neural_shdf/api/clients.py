"""Who sent the request being served, and whether they are still there.

``ClientMiddleware`` gives every HTTP request a ``Client`` (in the context variable
``current_client``): its fair-share key (the peer address, as uvicorn reports it: behind
a trusted proxy, the forwarded one) and, once asked for, an event set when the client
disconnects. The task runner uses both: computations wait for a slot of their client's
share of the compute pool, and work no remaining client waits for is cancelled.
"""

from __future__ import annotations

import asyncio
import contextlib
from contextvars import ContextVar

from starlette.types import ASGIApp, Message, Receive, Scope, Send

#: Fair-share key of work started without a client (background jobs).
BACKGROUND = "background"


class Client:
    """One request's client: who it is, and an event set when it disconnects.

    Watching for the disconnect reads the request's message stream, so it starts only
    when asked (``gone``), after the app read the body; from then on the app's own
    ``receive`` calls wait for the same disconnect instead of reading the stream too.
    """

    def __init__(self, key: str, receive: Receive) -> None:
        self.key = key
        self._receive = receive
        self._gone = asyncio.Event()
        self._watcher: asyncio.Task[None] | None = None

    async def receive(self) -> Message:
        """The app's ``receive``."""
        if self._watcher is not None:
            await self._gone.wait()
            return {"type": "http.disconnect"}
        message = await self._receive()
        if message["type"] == "http.disconnect":
            self._gone.set()
        return message

    def gone(self) -> asyncio.Event:
        """Set once the client has disconnected (watched from the first call on)."""
        if self._watcher is None and not self._gone.is_set():
            self._watcher = asyncio.create_task(self._watch())
        return self._gone

    async def _watch(self) -> None:
        while True:
            message = await self._receive()
            if message["type"] == "http.disconnect":
                self._gone.set()
                return

    async def close(self) -> None:
        if self._watcher is not None:
            self._watcher.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._watcher


current_client: ContextVar[Client | None] = ContextVar("current_client", default=None)


class ClientMiddleware:
    """Sets ``current_client`` for each HTTP request (and stops watching at its end)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        peer = scope.get("client")
        client = Client(str(peer[0]) if peer else "unknown", receive)
        token = current_client.set(client)
        try:
            await self.app(scope, client.receive, send)
        finally:
            current_client.reset(token)
            await client.close()
