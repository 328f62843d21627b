"""The Rerun server behind ``mimic log --serve``: the bundled ``rerun --serve-web`` bound to one interface.

Rerun's in-process ``serve_web_viewer`` (0.41) has no bind address: its HTTP server listens on
every interface, whatever the gRPC sink binds. The Rerun CLI that ships with rerun-sdk takes
``--bind`` for both of its servers (the web viewer's files over HTTP and the recording over
gRPC), so ``--serve`` runs it as a child process and the logger streams to it through a gRPC sink.
The child is started in a process group of its own and ended with the logger.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

log = logging.getLogger("mimic.log")
#: Interfaces that mean "every interface": the logger reaches the server on loopback then.
ANY_HOST = ("0.0.0.0", "::", "")


def rerun_binary() -> str:
    """The Rerun CLI binary bundled with rerun-sdk (not its Python wrapper, whose child would outlive it)."""
    import rerun_cli

    return str(Path(rerun_cli.__file__).parent / "rerun")


def end_group(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    """Stop a process started with ``start_new_session=True`` and everything it started."""
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout)
    except ProcessLookupError:
        pass


class RerunServer:
    """``rerun --serve-web --bind HOST``: gRPC on ``grpc_port``, the web viewer on ``web_port``.

    Args:
        bind_host: interface both servers listen on (loopback unless asked: they are unauthenticated).
        grpc_port, web_port: their TCP ports.

    Raises (from :meth:`start`):
        RuntimeError: the server exited or did not listen within the timeout (its output is in the text).
    """

    def __init__(self, bind_host: str, grpc_port: int, web_port: int) -> None:
        self.bind_host, self.grpc_port, self.web_port = bind_host, int(grpc_port), int(web_port)
        self.proc: subprocess.Popen | None = None

    @property
    def local_host(self) -> str:
        """Where this machine reaches the server (loopback for a bind to every interface)."""
        return "127.0.0.1" if self.bind_host in ANY_HOST else self.bind_host

    @property
    def sink_url(self) -> str:
        """The gRPC URL the logger streams to."""
        return f"rerun+http://{self.local_host}:{self.grpc_port}/proxy"

    def start(self, timeout: float = 20.0) -> RerunServer:
        """Start the server and wait until its gRPC port accepts connections."""
        argv = [
            rerun_binary(),
            "--serve-web",
            "--bind",
            self.bind_host,
            "--port",
            str(self.grpc_port),
            "--web-viewer-port",
            str(self.web_port),
        ]
        # Its output goes to an unnamed file: a pipe nobody drains would block it; read on failure.
        self._out = tempfile.TemporaryFile()  # noqa: SIM115 (lives as long as the server; closed in close())
        self.proc = subprocess.Popen(
            argv, stdout=self._out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True
        )
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                self._out.seek(0)
                out = self._out.read().decode(errors="replace").strip()
                code = self.proc.returncode
                self.close()
                raise RuntimeError(f"rerun --serve-web exited with {code}: {out[-400:]}")
            try:
                with socket.create_connection((self.local_host, self.grpc_port), timeout=0.5):
                    break
            except OSError:
                time.sleep(0.1)
        else:
            self.close()
            raise RuntimeError(
                f"rerun --serve-web did not listen on {self.local_host}:{self.grpc_port} in {timeout:.0f} s"
            )
        return self

    def close(self) -> None:
        """End the server (and its process group)."""
        if self.proc is not None:
            end_group(self.proc)
            self.proc = None
            self._out.close()
