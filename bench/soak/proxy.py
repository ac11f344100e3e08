"""A TCP proxy between the clients and the broker (on loopback, or the soak's LAN): it can cut every connection or
delay the traffic, which is how the soak injects network faults."""

from __future__ import annotations

import asyncio
import contextlib


class FaultyProxy:
    """Forwards `<listen>:<port>` to the broker; `cut()` drops all, `latency_s` delays bytes."""

    def __init__(self, target_host: str, target_port: int, listen: str = "127.0.0.1") -> None:
        self.target = (target_host, target_port)
        self.listen = listen  # loopback, or the soak's LAN address (--network)
        self.latency_s = 0.0
        self.refusing = False  # while set, new connections are closed at once (the link is down)
        self.port = 0
        self._server: asyncio.Server | None = None
        self._links: set[asyncio.Task[None]] = set()
        self._sockets: set[asyncio.StreamWriter] = set()  # both ends of every open link

    async def start(self) -> int:
        """Listen on a free port of `listen`; returns it."""
        self._server = await asyncio.start_server(self._accept, self.listen, 0)
        self.port = self._server.sockets[0].getsockname()[1]
        return self.port

    @property
    def open_links(self) -> int:
        """Connections forwarded now (a client on the broker behind, through this proxy)."""
        return len(self._links)

    def cut(self) -> int:
        """Drop every open connection (both ends see a reset); returns how many were dropped."""
        # Aborted, not cancelled: asyncio logs a cancelled connection handler as an error.
        for end in list(self._sockets):
            end.transport.abort()
        return len(self._links)

    async def close(self) -> None:
        """Stop listening and drop every connection."""
        if self._server is not None:
            self._server.close()
        self.cut()
        await asyncio.gather(*self._links, return_exceptions=True)

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.refusing:
            writer.close()
            return
        task = asyncio.current_task()
        assert task is not None
        self._links.add(task)
        upstream: asyncio.StreamWriter | None = None
        try:
            self._sockets.add(writer)
            up_reader, upstream = await asyncio.open_connection(*self.target)
            self._sockets.add(upstream)
            await asyncio.gather(self._pipe(reader, upstream), self._pipe(up_reader, writer))
        except (OSError, asyncio.IncompleteReadError):
            if upstream is None:
                # The broker is down: reset, as a refused connection would, not a clean close.
                writer.transport.abort()
        finally:
            self._links.discard(task)
            for end in (writer, upstream):
                if end is not None:
                    self._sockets.discard(end)
                    end.close()

    async def _pipe(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while data := await reader.read(65536):
                if self.latency_s > 0:
                    # Every chunk waits the same: order is kept, the link is just slow.
                    await asyncio.sleep(self.latency_s)
                writer.write(data)
                await writer.drain()
        finally:
            # One side ended: end the other, so neither client nor broker is left half-open.
            with contextlib.suppress(OSError):
                writer.close()
