"""`mimic log --serve` as a user runs it: both Rerun ports listen on loopback unless asked, and it serves.

The gRPC port carries the recording and the web port the viewer; neither authenticates, so
both must bind ``--bind-host`` (127.0.0.1 by default). Read from the kernel's socket table,
not from what the logger says.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest

from shared.bus import free_port

pytestmark = pytest.mark.integration
LISTEN = "0A"  # TCP state LISTEN in /proc/net/tcp


def _listening(port: int) -> list[str]:
    """Local addresses (hex, as in /proc/net/tcp{,6}) of the sockets listening on TCP ``port``."""
    out = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for row in Path(table).read_text().splitlines()[1:]:
            cols = row.split()
            addr, hexport = cols[1].rsplit(":", 1)
            if int(hexport, 16) == port and cols[3] == LISTEN:
                out.append(addr)
    return out


class _Output:
    """A child's output lines, read on a thread (a pipe nobody drains would block it)."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.lines: list[str] = []
        self._t = threading.Thread(target=lambda: self.lines.extend(proc.stdout), daemon=True)
        self._t.start()

    def text(self) -> str:
        return "".join(self.lines)[-1500:]


def _serve(tmp_path: Path, endpoint: str, *extra: str) -> tuple[subprocess.Popen, _Output, int, int, Path]:
    """Start ``mimic log --serve`` and wait until it records (both ports listening)."""
    grpc, web = free_port(), free_port()
    rrd = tmp_path / f"serve{grpc}.rrd"
    argv = [sys.executable, "-m", "services.cli", "log", "--serve", "--grpc-port", str(grpc), "--web-port", str(web)]
    argv += ["--rrd", str(rrd), "--session", f"serve{grpc}", "--connect", endpoint, *extra]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    out = _Output(proc)
    deadline = time.monotonic() + 90
    while not any("recording mimic/" in line for line in out.lines):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            proc.wait()
            pytest.fail(f"mimic log --serve did not start recording (exit {proc.returncode}): {out.text()}")
        time.sleep(0.2)
    return proc, out, grpc, web, rrd


def _stop(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def test_log_serve_binds_loopback_by_default_and_every_interface_when_asked(tmp_path, router):
    proc, out, grpc, web, rrd = _serve(tmp_path, router)
    try:
        # 127.0.0.1 little-endian hex; 00000000 (or an IPv6 ::) would be every interface
        assert _listening(grpc) == ["0100007F"], _listening(grpc)
        assert _listening(web) == ["0100007F"], _listening(web)
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=10) as page:
            assert page.status == 200 and b"<html" in page.read(4096).lower()
    finally:
        _stop(proc)
    assert proc.returncode == 0, out.text()
    assert rrd.exists() and rrd.stat().st_size > 0, out.text()
    assert not _listening(grpc) and not _listening(web), "the Rerun server outlived the logger"

    proc, out, grpc, web, _ = _serve(tmp_path, router, "--bind-host", "0.0.0.0")
    try:
        assert _listening(grpc) == ["00000000"] and _listening(web) == ["00000000"]
    finally:
        _stop(proc)
