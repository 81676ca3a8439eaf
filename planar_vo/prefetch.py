"""Decode the next frames in the background while the current one is processed.

Two producers with one interface: :class:`Prefetcher`, a thread (image decoding, zstd
and OpenCV release the GIL, the rest of its work does not), and
:class:`ProcessPrefetcher`, a forked child process with its own interpreter lock. Both
run at most ``depth`` items ahead, so memory stays flat.
"""
from __future__ import annotations

import mmap
import multiprocessing
import os
import pickle
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator

from planar_vo.core.errors import PartialResult

_DONE = object()
_END, _FAIL = "__end__", "__fail__"


def _same(x):
    return x


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


class ProcessPrefetcher:
    """Iterate ``source`` in a forked child process, at most ``depth`` items ahead.

    The thread of :class:`Prefetcher` shares the interpreter lock: on the demo log its
    Python work (MCAP records, corner bookkeeping: about a quarter of its samples in a
    py-spy profile) interleaved with the main thread's, and each waited for the other. A child
    process has its own lock. Items travel pickled (protocol 5); their large buffers
    (the images) through a ring of ``depth`` shared-memory slots of ``slot_bytes`` each
    (one copy out of the slot into the parent), the rest through a pipe. An item whose
    buffers do not fit a slot travels through the pipe whole.

    ``source`` is iterated in the child only, as it was when the child was forked: the
    child sees the parent's objects as of :meth:`__init__` and the parent never sees the
    child's changes, except what it hands back: ``pack(item)`` in the child makes what is
    sent, ``unpack(sent)`` in the parent makes what is yielded; ``finish()`` runs in the
    child after the last item (or after the source raised) and its (picklable) result is
    :attr:`finished` in the parent once the stream ended. ``child_init()`` runs first in
    the child (e.g. reopen files: the descriptors and their offsets are shared with the
    parent).

    As :class:`Prefetcher`: exceptions raised by ``source`` (picklable ones keep their
    type) are re-raised in the consumer where the stream stopped; ``busy_s`` and
    ``busy_cpu_s`` are the producer's own wall and CPU time; use as a context manager so
    that an early exit stops the child. ``cpu_s``: the child process's whole CPU time
    (all its threads), known once the stream ended. A child that dies without a word
    (killed, out of memory) ends the stream with :class:`PartialResult` after the items
    it sent. POSIX only (``fork``).
    """

    def __init__(self, source: Iterable, *, pack: Callable = _same, unpack: Callable = _same, depth: int = 4,
                 slot_bytes: int = 16 << 20, finish: Callable | None = None, child_init: Callable | None = None):
        ctx = multiprocessing.get_context("fork")
        self._slots, self._slot_bytes = max(1, depth), int(slot_bytes)
        self._ring = mmap.mmap(-1, self._slots * self._slot_bytes)  # shared with the child (MAP_SHARED)
        self._free = ctx.Semaphore(self._slots)
        self._rx, tx = ctx.Pipe(duplex=False)
        self._unpack = unpack
        self.busy_s = self.busy_cpu_s = self.cpu_s = 0.0
        self.finished = None
        self._ended = False
        self._proc = ctx.Process(target=self._child, args=(source, pack, tx, finish, child_init),
                                 name="planar-vo-reader", daemon=True)
        self._proc.start()
        tx.close()

    # ----------------------------------------------------------------- child
    def _child(self, source, pack, tx, finish, child_init) -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
        self._rx.close()
        busy = cpu = 0.0
        slot, failure = 0, None
        try:
            if child_init is not None:
                child_init()
            it = iter(source)
            while True:
                t0, c0 = time.perf_counter(), time.thread_time()
                try:
                    item = next(it)
                except StopIteration:
                    break
                bufs: list = []
                payload = pack(item)
                data = pickle.dumps(payload, protocol=5, buffer_callback=bufs.append)
                busy, cpu = busy + time.perf_counter() - t0, cpu + time.thread_time() - c0
                self._wait_for_slot()
                t0, c0 = time.perf_counter(), time.thread_time()
                tx.send(self._to_slot(slot, payload, bufs, data))
                slot = (slot + 1) % self._slots
                busy, cpu = busy + time.perf_counter() - t0, cpu + time.thread_time() - c0
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer
            failure = _picklable(exc)
        try:  # what the source did so far, also after a failure (a log cut short)
            done = finish() if finish is not None else None
        except BaseException as exc:  # noqa: BLE001
            done, failure = None, failure or _picklable(exc)
        try:
            tx.send((_FAIL if failure is not None else _END, (busy, cpu, time.process_time(), done, failure), None))
            tx.close()
        except OSError:  # the parent is gone (the pipe is closed): nobody to tell
            pass

    def _wait_for_slot(self) -> None:
        """Until the parent has copied the next slot's previous item out; exit if the
        parent is gone (killed: nobody would free a slot again)."""
        parent = os.getppid()
        while not self._free.acquire(timeout=1.0):
            if os.getppid() != parent:
                os._exit(1)

    def _to_slot(self, slot: int, payload, bufs: list, data: bytes) -> tuple:
        """``(slot, [(offset, nbytes)], pickle)``: the buffers ``bufs`` of ``payload``'s
        pickle ``data`` copied into the slot; or ``(None, None, payload pickled with its
        buffers in-band)`` when they do not fit."""
        views = [b.raw() for b in bufs]
        if sum(_padded(v.nbytes) for v in views) > self._slot_bytes:
            self._free.release()
            return None, None, pickle.dumps(payload, protocol=5)
        base, off, where = slot * self._slot_bytes, 0, []
        for v in views:
            self._ring[base + off:base + off + v.nbytes] = v
            where.append((off, v.nbytes))
            off += _padded(v.nbytes)
        return slot, where, data

    # ---------------------------------------------------------------- parent
    def __iter__(self) -> Iterator:
        ring = memoryview(self._ring)
        while not self._ended:
            try:
                slot, where, data = self._rx.recv()
            except EOFError:  # every write end is closed: the child died without a word
                self._ended = True
                self._proc.join(timeout=5.0)
                raise PartialResult(f"the reader process stopped (exit code {self._proc.exitcode}) before the "
                                    "end of the log; the frames it read are processed") from None
            if slot in (_END, _FAIL):
                self.busy_s, self.busy_cpu_s, self.cpu_s, self.finished, failure = where
                self._ended = True
                if failure is not None:
                    raise failure
                return
            if slot is None:
                yield self._unpack(pickle.loads(data))
                continue
            base = slot * self._slot_bytes
            bufs = [bytearray(ring[base + o:base + o + n]) for o, n in where]  # copied: the slot is reused
            self._free.release()
            yield self._unpack(pickle.loads(data, buffers=bufs))

    def close(self) -> None:
        if self._proc.is_alive() and not self._ended:
            self._proc.kill()
        self._proc.join(timeout=5.0)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(timeout=5.0)
        self._rx.close()

    def __enter__(self) -> "ProcessPrefetcher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _padded(n: int) -> int:
    return (n + 63) & ~63  # 64-byte alignment of every buffer in a slot


def _picklable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling (so the parent re-raises its type), else a
    RuntimeError with its type and message."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 - any exception that cannot be pickled
        return RuntimeError(f"{type(exc).__name__}: {exc}")


def process_prefetch_available() -> bool:
    """Whether :class:`ProcessPrefetcher` can run here: Linux (``fork`` is the platform's
    own start method; macOS's system libraries are not safe to fork with), and not in a
    daemonic process (a ``multiprocessing.Pool`` worker may not start children)."""
    return (sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods()
            and not multiprocessing.current_process().daemon)
