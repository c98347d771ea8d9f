"""Work computed a few items ahead on a second thread, in order (the sequence's images
decoded while the previous ones are tracked; IASM's frames built while the previous pair is
matched).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor


def computed_ahead[T](compute: Callable[[int], T], n: int, ahead: int) -> Iterator[tuple[int, T]]:
    """``(i, compute(i))`` for i = 0 .. n-1 in order, each computed up to ``ahead`` items in
    advance on a second thread, so the work overlaps what the caller does with the items
    before (for work that releases the interpreter: OpenCV, numpy, compiled kernels).
    An error raised by ``compute`` comes out where its item would have; the items not yet
    started are then dropped."""
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ahead")
    pending: deque[Future[T]] = deque()
    try:
        for i in range(n):
            while len(pending) < max(ahead, 1) and i + len(pending) < n:
                pending.append(pool.submit(compute, i + len(pending)))
            yield i, pending.popleft().result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
