"""Frames lost on the bus before they reached the recorder, from ``seq`` gaps.

"received = written" only says the recorder lost nothing itself. A mocap source numbers
its frames ``seq`` = 0, 1, 2, ... per source, so a jump of more than one between two
frames of one source on one key is frames the bus (or a congested router) dropped on
the way. Other streams skip seqs by design (retarget rejects, newest-wins queues), so
only mocap frames are counted.
"""

from __future__ import annotations

from shared.keys import Keys
from shared.messages import peek

#: Relative key whose seq gaps are losses (``mimic/<s>/mocap/frame``).
COUNTED = Keys("x").mocap_frame.split("/", 2)[2]


class SeqGaps:
    """Counts missing seqs per (key, source) of mocap frames.

    Attributes:
        missing: frames never received (sum of gaps).
        restarts: times a source began again from a lower seq (not a loss).
    """

    def __init__(self) -> None:
        self._last: dict[tuple[str, str], int] = {}
        self.missing = 0
        self.restarts = 0

    def step(self, key: str, payload: bytes) -> None:
        """Account one recorded message (ignored unless a mocap frame with a header)."""
        if not key.endswith("/" + COUNTED):
            return
        d = peek(payload)
        hdr = d.get("hdr") if d else None
        if not isinstance(hdr, list) or not hdr or not isinstance(hdr[0], int):
            return
        stream, seq = (key, str(d.get("src", ""))), hdr[0]
        last = self._last.get(stream)
        if last is not None:
            if seq > last + 1:
                self.missing += seq - last - 1
            elif seq <= last:
                self.restarts += 1
        self._last[stream] = seq
