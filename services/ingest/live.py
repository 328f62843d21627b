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

    def _sanitize(
        self, source: str, frame: HumanFrame, issues: list[Issue], sender_t0: bool = False
    ) -> tuple[HumanFrame | None, list[Issue]]:
        san = self.sanitizers.get(source)
        if san is None:
            # Xsens frames and restamped ones carry the arrival time as t0, which cannot tell a
            # restarted sender from a late packet; the sender's own t0 can.
            san = self.sanitizers[source] = FrameSanitizer(trust_t0=sender_t0)
        return san.step(frame, issues)

    def step(self, source: str, payload: bytes, now_ns: int) -> tuple[HumanFrame | None, list[Issue]]:
        """One datagram from ``source`` ("udp" or "xsens").

        Returns:
            (frame to publish or None, issues found); an unreadable datagram
            gives (None, [Issue(reason, "dropped", detail)]).
        """
        sender_t0 = False
        try:
            if source == "udp":
                frame, issues = decode_lenient(payload)
                sender_t0 = not self.restamp and frame.hdr.t0 > 0
                if not sender_t0:
                    frame.hdr.t0 = now_ns
            elif source == "xsens":
                frame, issues = self.xsens.step(payload, now_ns), []
                if frame is None:
                    return None, []
            else:
                raise ValueError(f"unknown source {source!r}")
        except (MessageError, MvnError) as exc:
            return None, [Issue(exc.reason, "dropped", f"{source}: {exc.detail}")]
        return self._sanitize(source, frame, issues, source == "udp" and sender_t0)
