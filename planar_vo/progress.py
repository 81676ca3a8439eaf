"""A small progress line on stderr: frames, frames per second and estimator counts."""
from __future__ import annotations

import sys
import time


class Progress:
    """``Progress(total)``; call ``update(n_done, **counts)`` per frame and ``close()`` at the end.

    On a terminal the line is redrawn in place (at most 5 times a second); otherwise a
    line is printed every 10 seconds so that CI logs stay short.
    """

    def __init__(self, total: int | None, label: str = "frames", enabled: bool = True, stream=None):
        self.total = total
        self.label = label
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.perf_counter()
        self._last = 0.0
        self._line = ""

    def update(self, done: int, **counts) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if now - self._last < (0.2 if self.tty else 10.0):
            return
        self._last = now
        self._draw(done, counts, now)

    def _draw(self, done: int, counts: dict, now: float) -> None:
        fps = done / max(now - self.t0, 1e-9)
        total = f"/{self.total}" if self.total else ""
        extra = " ".join(f"{k} {v}" for k, v in counts.items())
        line = f"{self.label} {done}{total} | {fps:5.1f} fps | {extra}"
        if self.tty:
            self.stream.write("\r" + line.ljust(len(self._line)))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()
        self._line = line

    def close(self, done: int, **counts) -> None:
        if not self.enabled:
            return
        self._draw(done, counts, time.perf_counter())
        if self.tty:
            self.stream.write("\n")
        self.stream.flush()
