"""Frames written by a second thread while the next frame is computed.

Why: at 2K-4K an export or a render spends a fifth to a quarter of each frame compressing and writing its file
(OpenEXR's and OpenImageIO's writers, and PNG's, run without Python's lock), time the next frame's evaluation can
use. At most ``ahead`` frames wait to be written, so memory holds at most that many more frames. What follows a
write (a progress line, a file's size) runs in the caller's thread, in frame order, once its file is whole.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from types import TracebackType
from typing import Any, Generic, TypeVar

T = TypeVar("T")

#: Frames that may wait to be written while the next is computed: one is enough to keep the writer busy (a frame's
#: computation takes longer than its write), and each more holds one more frame in memory.
FRAMES_AHEAD = 1


class WriteAhead(Generic[T]):
    """``submit(write, ...)`` a frame's write and go on computing the next; ``done(tag, result)`` is called in the
    caller's thread, in the order submitted, once a write has finished. Used as a context manager: leaving it
    normally waits for every write; leaving it by an exception (a failure, a cancel) lets the write under way end
    (its file whole) and starts none of those queued, so nothing writes into a folder being discarded. A write's
    exception is raised in the caller's thread by the ``submit`` or the exit that waits for it."""

    def __init__(self, ahead: int, done: Callable[[Any, T], None], name: str = "writer") -> None:
        self.ahead = max(0, int(ahead))
        self._done = done
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)
        self._pending: deque[tuple[Any, Future[T]]] = deque()

    def submit(self, tag: Any, write: Callable[..., T], *args: Any, **kwargs: Any) -> None:
        """Queue ``write(*args, **kwargs)``; then wait for the oldest writes until at most ``ahead`` are pending."""
        self._pending.append((tag, self._pool.submit(write, *args, **kwargs)))
        while len(self._pending) > self.ahead:
            self._finish()

    def _finish(self) -> None:
        tag, future = self._pending.popleft()
        self._done(tag, future.result())

    def __enter__(self) -> WriteAhead[T]:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        try:
            while kind is None and self._pending:
                self._finish()
        finally:
            self._pool.shutdown(wait=True, cancel_futures=True)


__all__ = ["FRAMES_AHEAD", "WriteAhead"]
