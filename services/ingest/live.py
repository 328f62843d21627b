"""Live sources -> sanitized HumanFrames (pure; the sockets live in :mod:`services.ingest.cli`).

Two datagram sources, each with its own :class:`FrameSanitizer` (their
sequence numbers are independent):

* ``udp``: HumanFrame msgpack datagrams, the same contract as the bus
  (:meth:`shared.messages.HumanFrame.encode`), decoded leniently so repairs
  are possible;
* ``xsens``: MVN network streaming pose datagrams (type 02).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from services.ingest.sanitizer import FrameSanitizer, Issue, decode_lenient
from services.ingest.xsens import MvnDecoder, MvnError
from shared.messages import HumanFrame, MessageError


@dataclass
class LiveIngest:
    """Turn raw datagrams into frames to publish plus the issues to count.

    Attributes:
        xsens: decoder for MVN datagrams.
        restamp: replace the sender's ``hdr.t0`` by the receive time (sender clock not trusted).
    """

    xsens: MvnDecoder = field(default_factory=MvnDecoder)
    restamp: bool = False
    sanitizers: dict[str, FrameSanitizer] = field(default_factory=dict)

    def _sanitize(self, source: str, frame: HumanFrame, issues: list[Issue]) -> tuple[HumanFrame | None, list[Issue]]:
        san = self.sanitizers.setdefault(source, FrameSanitizer())
        return san.step(frame, issues)

    def step(self, source: str, payload: bytes, now_ns: int) -> tuple[HumanFrame | None, list[Issue]]:
        """One datagram from ``source`` ("udp" or "xsens").

        Returns:
            (frame to publish or None, issues found); an unreadable datagram
            gives (None, [Issue(reason, "dropped", detail)]).
        """
        try:
            if source == "udp":
                frame, issues = decode_lenient(payload)
                if self.restamp or frame.hdr.t0 <= 0:
                    frame.hdr.t0 = now_ns
            elif source == "xsens":
                frame, issues = self.xsens.step(payload, now_ns), []
                if frame is None:
                    return None, []
            else:
                raise ValueError(f"unknown source {source!r}")
        except (MessageError, MvnError) as exc:
            return None, [Issue(exc.reason, "dropped", f"{source}: {exc.detail}")]
        return self._sanitize(source, frame, issues)
