"""The live event stream: new memories, skipped frames and answers, fanned out to listeners.

Events are published from any thread (the writer thread, a request's worker thread) and read by
async listeners (one per open `/events` stream). A listener that does not keep up loses its
oldest events rather than holding memory: the stream is a view, the memory is the record.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from typing import Any

QUEUE_SIZE = 256  # events buffered per listener
MAX_LISTENERS = 64


class StreamRefused(RuntimeError):
    pass


class EventBus:
    """Thread-safe publish, async subscribe."""

    def __init__(self, max_listeners: int = MAX_LISTENERS) -> None:
        self.max_listeners = max_listeners
        self._listeners: set[tuple[asyncio.AbstractEventLoop, asyncio.Queue[dict[str, Any] | None]]] = set()
        self._lock = threading.Lock()
        self._seq = 0
        self._closed = False

    def publish(self, kind: str, data: dict[str, Any]) -> None:
        """Send `{"type": kind, "seq": n, **data}` to every listener (never blocks)."""
        with self._lock:
            self._seq += 1
            event = {"type": kind, "seq": self._seq, **data}
            listeners = list(self._listeners)
        for loop, q in listeners:
            try:
                loop.call_soon_threadsafe(_put_latest, q, event)
            except RuntimeError:  # that listener's loop is closed
                self._drop(loop, q)

    def close(self) -> None:
        """End every stream and refuse new ones (the service is stopping)."""
        with self._lock:
            self._closed = True
            listeners = list(self._listeners)
        for loop, q in listeners:
            with contextlib.suppress(RuntimeError):  # that listener's loop is closed
                loop.call_soon_threadsafe(_put_latest, q, None)

    def subscribe(self) -> Subscription:
        """A new listener, from now on; close it (or use it as a context manager) when done."""
        sub = Subscription(self, asyncio.get_running_loop())
        with self._lock:
            if self._closed:
                raise StreamRefused("the service is stopping")
            if len(self._listeners) >= self.max_listeners:
                raise StreamRefused(f"{self.max_listeners} event streams are open already")
            self._listeners.add((sub.loop, sub.queue))
        return sub

    def _drop(self, loop: asyncio.AbstractEventLoop, q: asyncio.Queue[dict[str, Any] | None]) -> None:
        with self._lock:
            self._listeners.discard((loop, q))

    @property
    def listeners(self) -> int:
        with self._lock:
            return len(self._listeners)


class Subscription:
    """One listener's queue. `next(timeout)` returns the next event, None when the bus closed, or
    raises TimeoutError when nothing came (the stream then sends a keep-alive)."""

    def __init__(self, bus: EventBus, loop: asyncio.AbstractEventLoop) -> None:
        self.bus, self.loop = bus, loop
        self.queue: asyncio.Queue[dict[str, Any] | None] = asyncio.Queue(QUEUE_SIZE)

    async def next(self, timeout: float) -> dict[str, Any] | None:
        return await asyncio.wait_for(self.queue.get(), timeout)

    def close(self) -> None:
        self.bus._drop(self.loop, self.queue)

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _put_latest(q: asyncio.Queue[dict[str, Any] | None], event: dict[str, Any] | None) -> None:
    while True:
        try:
            q.put_nowait(event)
            return
        except asyncio.QueueFull:
            q.get_nowait()  # drop the oldest
