"""MCAP files of bus traffic: one channel per Zenoh key, msgpack payloads as sent.

Layout of a recording:

* channel topic = the full Zenoh key (``mimic/<session>/...``), schema-less,
  ``message_encoding = "msgpack"``; channel metadata ``type`` holds the
  message type name seen first on that key (``HumanFrame``, ...).
* message ``log_time`` = wall-clock receive time [ns since epoch];
  ``publish_time`` = ``hdr.t0`` of the payload [ns] when it has one, else the
  Zenoh timestamp, else the receive time; ``sequence`` = receive order.

Crash safety: chunks are small and the writer is flushed periodically, so a
SIGKILL loses at most the last unflushed period. :func:`read_recording`
reads files without summary/footer (killed recordings) up to the last
complete record.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from mcap.exceptions import McapError
from mcap.records import Channel, Footer, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from shared.messages import peek

ENCODING = "msgpack"
#: First bytes of every MCAP file (MCAP spec, version 0).
MCAP0_MAGIC = b"\x89MCAP0\r\n"
LIBRARY = "mimic-recorder"
#: Metadata record name holding the recorder's final counts.
SUMMARY_METADATA = "mimic.recorder"


def payload_info(payload: bytes) -> tuple[str, int | None]:
    """Message type name and ``hdr.t0`` [ns] of a payload, without full validation.

    Returns ``("", None)`` for payloads that are not mimic messages; never raises.
    """
    d = peek(payload)
    if d is None:
        return "", None
    t = d.get("t")
    hdr = d.get("hdr")
    t0 = None
    if isinstance(hdr, list) and len(hdr) == 3 and isinstance(hdr[2], int) and 0 <= hdr[2] < 2**64:
        t0 = hdr[2]
    return (t if isinstance(t, str) else ""), t0


class RecordingWriter:
    """Append bus messages to an MCAP file, crash-tolerant.

    Args:
        path: output file (parent directories are created).
        chunk_size: target chunk size [bytes]; a chunk is written once it is full.
        compression: "zstd", "lz4" or "none".
    """

    def __init__(self, path: str | Path, chunk_size: int = 256 * 1024, compression: str = "zstd"):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: BinaryIO = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression]
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=comp)
        self._writer.start(profile="", library=LIBRARY)
        self._channels: dict[str, int] = {}
        self.written = 0
        self._closed = False

    def write(self, key: str, payload: bytes, log_time: int, publish_time: int | None = None) -> None:
        """Append one message.

        Args:
            key: Zenoh key it was received on (becomes the channel topic).
            payload: bytes as received.
            log_time: receive time [ns since epoch].
            publish_time: source time [ns since epoch]; derived from ``hdr.t0`` when None.
        """
        msg_type, t0 = payload_info(payload)
        channel = self._channels.get(key)
        if channel is None:
            channel = self._writer.register_channel(key, ENCODING, 0, {"type": msg_type})
            self._channels[key] = channel
        pub = publish_time if publish_time is not None else (t0 if t0 is not None else log_time)
        self._writer.add_message(channel, log_time, payload, pub, self.written)
        self.written += 1

    def flush(self) -> None:
        """Close the open chunk and push it to the OS: everything so far survives a SIGKILL."""
        self._writer.flush()

    def close(self, summary: dict[str, str] | None = None) -> None:
        """Write the summary/footer (and an optional metadata record) and close the file."""
        if self._closed:
            return
        if summary:
            self._writer.add_metadata(SUMMARY_METADATA, {k: str(v) for k, v in summary.items()})
        self._writer.finish()
        self._file.close()
        self._closed = True


@dataclass(slots=True)
class Recorded:
    """One recorded message."""

    key: str
    data: bytes
    log_time: int  # receive time [ns since epoch]
    publish_time: int  # hdr.t0 / source time [ns since epoch]
    sequence: int  # receive order


@dataclass
class Recording:
    """Iterate the messages of an MCAP recording, complete or cut short by a crash.

    After iteration, :attr:`complete` says whether the footer was reached and
    :attr:`error` holds what stopped a truncated read.
    """

    path: Path
    complete: bool = False
    error: str = ""
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)

    def __iter__(self) -> Iterator[Recorded]:
        self.complete, self.error = False, ""
        with open(self.path, "rb") as f:
            reader = StreamReader(f, record_size_limit=1 << 30)
            try:
                for rec in reader.records:
                    if isinstance(rec, Message):
                        ch = self.channels.get(rec.channel_id)
                        if ch is None:
                            raise McapError(f"message on unknown channel {rec.channel_id}")
                        yield Recorded(ch.topic, rec.data, rec.log_time, rec.publish_time, rec.sequence)
                    elif isinstance(rec, Channel):
                        self.channels[rec.id] = rec
                    elif isinstance(rec, Metadata):
                        self.metadata[rec.name] = dict(rec.metadata)
                    elif isinstance(rec, Footer):
                        self.complete = True
            # A file cut by SIGKILL ends inside a record: the mcap reader then hits
            # end of file in its own parser (McapError) or in struct unpacking.
            except (McapError, struct.error, EOFError) as exc:
                self.error = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


def read_recording(path: str | Path) -> Recording:
    """A :class:`Recording` over ``path``.

    Raises:
        FileNotFoundError: no such file.
        ValueError: the file does not start like an MCAP file (a file cut before
            the end of its magic, e.g. killed at once, is an empty recording).
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"recording {p} does not exist")
    with open(p, "rb") as f:
        head = f.read(len(MCAP0_MAGIC))
    if head != MCAP0_MAGIC[: len(head)]:
        raise ValueError(f"{p} is not an MCAP file")
    return Recording(p)
