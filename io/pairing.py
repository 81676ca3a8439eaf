"""Streaming association of colour and depth messages by timestamp.

The matching is the TUM benchmark's ``associate.py`` rule: among all colour/depth
candidates with ``|c - d| <= tolerance``, take pairs in order of increasing ``|c - d|``,
each message used at most once. It is computed online: the candidate graph splits into
independent clusters wherever the merged stamp sequence leaves a gap larger than the
tolerance, so each cluster (usually one colour and one depth message) is solved and
released as soon as a later message proves it closed. Memory does not grow with the
log; ``max_pending`` bounds a cluster when the tolerance exceeds the frame period (its
messages older than the tolerance are then settled early, an approximation at the cut).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

COLOR, DEPTH = 0, 1


@dataclass
class Pair:
    color_stamp: float
    color: Any
    depth_stamp: float
    depth: Any


@dataclass
class Unpaired:
    side: int  # COLOR or DEPTH
    stamp: float


class StampPairer:
    """Feed ``push(side, stamp, payload)`` in stamp order, then ``finish()``.

    Both return lists of :class:`Pair` / :class:`Unpaired` events ordered by stamp.
    """

    def __init__(self, tolerance: float = 0.02, max_pending: int = 32):
        if not tolerance >= 0:
            raise ValueError(f"sync tolerance must be >= 0 s, got {tolerance}")
        self.tolerance = float(tolerance)
        self.max_pending = int(max_pending)
        self._pending: list[tuple[float, int, Any]] = []  # (stamp, side, payload)
        self._latest = -float("inf")

    def push(self, side: int, stamp: float, payload: Any) -> list:
        out = []
        # Nothing pushed from now on can lie within the tolerance of a pending message
        # once the newest stamp is more than the tolerance past all of them.
        if self._pending and stamp - self._latest > self.tolerance:
            out = self._solve(len(self._pending))
        self._pending.append((stamp, side, payload))
        self._latest = max(self._latest, stamp)
        if len(self._pending) > self.max_pending:
            # Settle the messages that are already a tolerance old (at least half of them);
            # the newer ones wait for their partners.
            old = sum(1 for it in self._pending if it[0] < self._latest - self.tolerance)
            out += self._solve(max(old, len(self._pending) // 2))
        return out

    def finish(self) -> list:
        return self._solve(len(self._pending))

    @property
    def pending(self) -> int:
        """Messages held back, waiting for their cluster to close."""
        return len(self._pending)

    def _solve(self, settle: int) -> list:
        """Greedy smallest-gap matching of the pending messages; release the first ``settle``
        (and their partners), keep the rest pending."""
        items = self._pending
        colors = [i for i, it in enumerate(items) if it[1] == COLOR]
        depths = [i for i, it in enumerate(items) if it[1] == DEPTH]
        cands = sorted((abs(items[c][0] - items[d][0]), c, d) for c in colors for d in depths
                       if abs(items[c][0] - items[d][0]) <= self.tolerance)
        partner: dict[int, int] = {}
        for _, c, d in cands:
            if c not in partner and d not in partner:
                partner[c], partner[d] = d, c
        release = set(range(settle)) | {partner[i] for i in range(settle) if i in partner}
        out: list = []
        for i in sorted(release):
            stamp, side, payload = items[i]
            if i not in partner:
                out.append((stamp, Unpaired(side, stamp)))
            elif side == COLOR:
                d = items[partner[i]]
                out.append((stamp, Pair(stamp, payload, d[0], d[2])))
        self._pending = [it for i, it in enumerate(items) if i not in release]
        out.sort(key=lambda e: e[0])
        return [e for _, e in out]
