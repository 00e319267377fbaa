"""A TCP relay that adds latency: what `tc netem delay` would do, for a kernel without netem.

Each chunk is forwarded `delay ± jitter` seconds later, never before the chunk ahead of it;
`start()` returns the address it listens on, `close()` closes everything. Its rules:
docs/FAULTS.md, "Network faults".
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time

import numpy as np

CHUNK = 64 * 1024
MAX_PENDING = 256


class DelayRelay:
    """Forwards TCP from `listen` (host, port; port 0: any free one) to `target`, delaying
    each chunk by a draw from uniform[delay_s − jitter_s, delay_s + jitter_s]."""

    def __init__(self, *, listen: tuple[str, int], target: tuple[str, int], delay_s: float,
                 jitter_s: float = 0.0, rng: np.random.Generator) -> None:
        if delay_s < 0 or jitter_s < 0 or jitter_s > delay_s:
            raise ValueError(f"delay relay: got delay {delay_s} s ± {jitter_s} s; need "
                             "0 <= jitter <= delay")
        self.listen, self.target = listen, target
        self.delay_s, self.jitter_s = delay_s, jitter_s
        self._rng = rng
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True,
                                        name="delay-relay")
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self.connections = 0
        """Connections accepted so far."""
        self.listen_address: tuple[str, int] = listen
        """Where it listens (the port bound, once started)."""

    def start(self) -> tuple[str, int]:
        """Listen; returns the (host, port) bound."""
        self._thread.start()
        self._server = asyncio.run_coroutine_threadsafe(
            asyncio.start_server(self._accept, *self.listen), self._loop).result(10)
        host, port = self._server.sockets[0].getsockname()[:2]
        self.listen_address = (str(host), int(port))
        return self.listen_address

    def close(self) -> None:
        """Stop listening, close every relayed connection, end the thread."""
        if not self._thread.is_alive():
            return
        asyncio.run_coroutine_threadsafe(self._shutdown(), self._loop).result(10)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        self._loop.close()

    def __enter__(self) -> DelayRelay:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    async def _shutdown(self) -> None:
        if self._server is not None:
            self._server.close()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    def _draw_s(self) -> float:
        if self.jitter_s == 0:
            return self.delay_s
        return float(self._rng.uniform(self.delay_s - self.jitter_s,
                                       self.delay_s + self.jitter_s))

    async def _accept(self, client_r: asyncio.StreamReader,
                      client_w: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        self.connections += 1
        try:
            try:
                target_r, target_w = await asyncio.open_connection(*self.target)
            except OSError:
                client_w.close()
                return
            pipes = [asyncio.create_task(self._pipe(client_r, target_w)),
                     asyncio.create_task(self._pipe(target_r, client_w))]
            try:
                # one direction failing breaks the path: the other is cancelled
                done, _ = await asyncio.wait(pipes, return_when=asyncio.FIRST_EXCEPTION)
                if any(t.exception() for t in done if not t.cancelled()):
                    for pipe in pipes:
                        pipe.cancel()
                await asyncio.gather(*pipes, return_exceptions=True)
            finally:
                for pipe in pipes:
                    pipe.cancel()
                for writer in (client_w, target_w):
                    writer.close()
        except asyncio.CancelledError:
            pass  # closed by `close()`: nothing left to do (a cancelled handler task is
            # reported as an error by asyncio's stream callback in Python 3.11)
        finally:
            self._tasks.discard(task)

    async def _pipe(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """One direction: read chunks, stamp each with its due time, write each when due."""
        pending: asyncio.Queue[tuple[float, bytes | None]] = asyncio.Queue(MAX_PENDING)

        async def read() -> None:
            last_due = 0.0
            try:
                while data := await reader.read(CHUNK):
                    last_due = max(time.monotonic() + self._draw_s(), last_due)  # keep order
                    await pending.put((last_due, data))
            except OSError:
                await pending.put((0.0, None))  # broken: no more data will come
            else:
                await pending.put((last_due, b""))  # end of stream, after what it sent

        reading = asyncio.create_task(read())
        try:
            while True:
                due, data = await pending.get()
                if data is None:
                    raise ConnectionResetError("the other side of the relay broke")
                wait_s = due - time.monotonic()
                if wait_s > 0:
                    await asyncio.sleep(wait_s)
                if not data:
                    with contextlib.suppress(OSError):
                        writer.write_eof()
                    break
                writer.write(data)
                await writer.drain()
            await reading
        finally:
            reading.cancel()
