"""Decode the next frames in a background thread while the current one is processed.

Image decoding (cv2.imdecode, zstd) releases the GIL, so on a 2-core machine reading
overlaps the front-end almost fully. The queue is bounded, so memory stays flat.
"""
from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterable, Iterator

_DONE = object()


class Prefetcher:
    """Iterate ``source`` in a thread, at most ``depth`` items ahead.

    Exceptions raised by ``source`` are re-raised in the consumer at the point where the
    stream stopped. ``busy_s`` is the producer's own time (reading and decoding), wall
    clock; ``busy_cpu_s`` the same in CPU time of the producer thread.
    Use as a context manager so that an early exit (Ctrl-C) stops the thread.
    """

    def __init__(self, source: Iterable, depth: int = 4):
        self._source = source
        self._q: queue.Queue = queue.Queue(maxsize=max(1, depth))
        self._stop = threading.Event()
        self.busy_s = 0.0
        self.busy_cpu_s = 0.0
        self._thread = threading.Thread(target=self._run, name="planar-vo-reader", daemon=True)
        self._thread.start()

    def _put(self, item) -> bool:
        while not self._stop.is_set():
            try:
                self._q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        it = iter(self._source)
        try:
            while not self._stop.is_set():
                t0, c0 = time.perf_counter(), time.thread_time()
                try:
                    item = next(it)
                except StopIteration:
                    break
                finally:
                    self.busy_s += time.perf_counter() - t0
                    self.busy_cpu_s += time.thread_time() - c0
                if not self._put(item):
                    break
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer
            self._put(("__error__", exc))
            return
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                close()
        self._put(_DONE)

    def __iter__(self) -> Iterator:
        while True:
            item = self._q.get()
            if item is _DONE:
                return
            if isinstance(item, tuple) and len(item) == 2 and item[0] == "__error__":
                raise item[1]
            yield item

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)

    def __enter__(self) -> "Prefetcher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
