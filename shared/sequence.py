"""Sequence numbers: frame ordering (:class:`SequenceGuard`) and lost-message counting (:class:`GapCounter`).

:class:`SequenceGuard` is the one order guard for every consumer of a frame stream (ingest
sanitizer, retarget).

The rule, per source:

* A frame is in order when its ``seq`` is above the last accepted one and its ``stamp``
  [s] is later than the last accepted one's. Otherwise it is rejected with a reason:
  ``duplicate_seq`` (same seq), ``seq_backwards`` (lower seq) or ``time_backwards``
  (higher seq, stamp not later).
* A **restart** of the source (a replayed clip, a rebooted device: seq and clock begin
  again) is recognised, and the frame accepted as the first of a new stream, when

  - its ``seq`` is not above the last accepted one but it entered the bus later (``t0``,
    wall clock [ns] stamped by the publisher, later than the last accepted frame's): a frame
    made after the last one with a lower ``seq`` can only come from a restarted source (a
    duplicated or reordered packet carries its original, earlier ``t0``), so one frame is
    enough (``trust_t0``; off where ``t0`` is stamped on arrival, e.g. ``ingest --restamp``), or
  - its ``seq`` is more than ``reset_gap`` below the last accepted one (an obvious
    restart: one frame is enough), or
  - ``resync_after`` frames in a row were out of order (a restart that jumped back only a
    little, or a clock that jumped back).

  The verdict then says ``restarted`` (reason ``seq_reset``) so the caller can drop its
  per-stream state (velocity filters, held poses).

State is kept per source name (``check(hdr, source)``), so streams of several sources
interleaved on one key are each judged against their own history.

:class:`GapCounter` counts messages lost between a publisher and a subscriber from a
per-publisher counter (the bus stamps one on every sample, see :mod:`shared.bus`). It is
apart from the guard on purpose: the header ``seq`` of a derived message (targets,
commands, states) skips legitimately wherever an upstream service rejected or superseded
a frame, so gaps in it would count one drop again at every later hop.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

from shared.messages import Header


@dataclass(frozen=True)
class Verdict:
    """What the guard says about one frame.

    Attributes:
        ok: the frame may be used (in order, or the first of a restarted stream).
        reason: rejection tag when not ok; "seq_reset" when ok because the source restarted.
        detail: human-readable text.
    """

    ok: bool
    reason: str | None = None
    detail: str = ""

    @property
    def restarted(self) -> bool:
        return self.reason == "seq_reset"


@dataclass
class _Stream:
    seq: int
    stamp: float
    t0: int = 0
    bad_in_row: int = 0


class SequenceGuard:
    """Judges frame order per source; see the module docstring for the rule.

    Args:
        reset_gap: a seq this far below the last accepted one is a restart at once.
        resync_after: consecutive out-of-order frames after which the source counts as restarted.
        trust_t0: a lower or equal seq with a later ``t0`` is a restart at once (see the module doc).
    """

    def __init__(self, reset_gap: int = 1000, resync_after: int = 30, trust_t0: bool = True):
        if reset_gap < 1 or resync_after < 1:
            raise ValueError(f"reset_gap ({reset_gap}) and resync_after ({resync_after}) must be >= 1")
        self.reset_gap = reset_gap
        self.resync_after = resync_after
        self.trust_t0 = trust_t0
        self._streams: dict[str, _Stream] = {}

    def check(self, hdr: Header, source: str = "") -> Verdict:
        """Judge ``hdr`` against ``source``'s last accepted frame (does not accept it: see :meth:`accept`)."""
        last = self._streams.get(source)
        if last is None:
            return Verdict(True)
        if self.trust_t0 and hdr.seq <= last.seq and last.t0 > 0 and hdr.t0 > last.t0:
            return Verdict(
                True, "seq_reset", f"seq {last.seq} -> {hdr.seq} on a newer frame (t0 later): source restarted"
            )
        if hdr.seq == last.seq:
            reason, detail = "duplicate_seq", f"seq {hdr.seq} repeated"
        elif hdr.seq < last.seq:
            if last.seq - hdr.seq > self.reset_gap:
                return Verdict(True, "seq_reset", f"seq jumped back {last.seq} -> {hdr.seq}: source restarted")
            reason, detail = "seq_backwards", f"seq {hdr.seq} after {last.seq}"
        elif not hdr.stamp > last.stamp:
            reason, detail = "time_backwards", f"stamp {hdr.stamp:.6f} s not after {last.stamp:.6f} s"
        else:
            last.bad_in_row = 0
            return Verdict(True)
        last.bad_in_row += 1
        if last.bad_in_row >= self.resync_after:
            return Verdict(
                True, "seq_reset", f"{last.bad_in_row} frames out of order (last: {detail}): source restarted"
            )
        return Verdict(False, reason, detail)

    def accept(self, hdr: Header, source: str = "") -> None:
        """Record ``hdr`` as ``source``'s last used frame."""
        self._streams[source] = _Stream(hdr.seq, hdr.stamp, hdr.t0)

    def last_stamp(self, source: str = "") -> float | None:
        """Stamp [s] of ``source``'s last accepted frame (None before the first)."""
        last = self._streams.get(source)
        return None if last is None else last.stamp

    def forget(self, source: str | None = None) -> None:
        """Drop the history of ``source`` (None: of every source)."""
        if source is None:
            self._streams.clear()
        else:
            self._streams.pop(source, None)


class GapCounter:
    """Messages missing between consecutive samples of each publisher (per-publisher counters).

    A publisher numbers its samples 1, 2, 3, ...; :meth:`see` returns how many numbers were
    skipped since that publisher's previous sample, i.e. samples lost on the way (in Zenoh under
    congestion, in the kernel, in a router). A number not above the last one (a publisher that
    restarted with the same id, a duplicate) starts that publisher's count afresh and is no gap.
    Thread-safe: Zenoh may deliver on several threads.

    Args:
        max_sources: publishers remembered; the least recently seen is forgotten beyond this
            (publishers that come and go must not grow the table forever).
    """

    def __init__(self, max_sources: int = 64):
        self.max_sources = max(1, int(max_sources))
        self.total = 0
        self._last: OrderedDict[int, int] = OrderedDict()
        self._lock = threading.Lock()

    def see(self, source: int, number: int) -> int:
        """Record sample ``number`` of publisher ``source``; return the count of samples skipped before it."""
        with self._lock:
            last = self._last.get(source)
            self._last[source] = number
            self._last.move_to_end(source)
            if len(self._last) > self.max_sources:
                self._last.popitem(last=False)
            if last is None or number <= last:
                return 0
            gap = number - last - 1
            self.total += gap
            return gap
