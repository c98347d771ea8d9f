"""Work computed a few items ahead on a second thread, in order (the sequence's images
decoded while the previous ones are tracked; IASM's frames built while the previous pair is
matched; the targetless check's frames decoded while the laser odometry runs).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from types import TracebackType


class Ahead[T]:
    """``(i, compute(i))`` for i = 0 .. n-1 in order, each computed up to ``ahead`` items in
    advance on ``workers`` other threads (one by default; with two, items are computed two
    at a time, for a caller that would otherwise wait on them), the first ``ahead``
    submitted at once (so they are under way while the caller does other work before it
    asks for them). Use as a context manager, or call :meth:`close`: the items not yet
    started are then dropped and the threads are joined. An error raised by ``compute``
    comes out where its item would have."""

    def __init__(self, compute: Callable[[int], T], n: int, ahead: int, workers: int = 1) -> None:
        self._compute = compute
        self._n = n
        self._ahead = max(ahead, 1)
        self._pool = ThreadPoolExecutor(max_workers=max(workers, 1), thread_name_prefix="ahead")
        self._pending: deque[Future[T]] = deque()
        self._submitted = 0
        self._fill()

    def _fill(self) -> None:
        while len(self._pending) < self._ahead and self._submitted < self._n:
            self._pending.append(self._pool.submit(self._compute, self._submitted))
            self._submitted += 1

    def __iter__(self) -> Iterator[tuple[int, T]]:
        try:
            for i in range(self._n):
                self._fill()
                yield i, self._pending.popleft().result()
        finally:
            self.close()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> Ahead[T]:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def computed_ahead[T](compute: Callable[[int], T], n: int, ahead: int) -> Iterator[tuple[int, T]]:
    """``(i, compute(i))`` for i = 0 .. n-1 in order, each computed up to ``ahead`` items in
    advance on a second thread, so the work overlaps what the caller does with the items
    before (for work that releases the interpreter: OpenCV, numpy, compiled kernels).
    The work starts when the first item is asked for (:class:`Ahead` starts it at once).
    An error raised by ``compute`` comes out where its item would have; the items not yet
    started are then dropped."""
    yield from Ahead(compute, n, ahead)
