"""A recording opened in the Rerun web viewer inside headless Chromium, looked at through screenshots.

:class:`WebViewer` serves an ``.rrd`` with the Rerun CLI that ships with rerun-sdk
(``rerun --serve-web FILE``: the web viewer's files over HTTP, the recording over gRPC, both on
loopback), opens the viewer URL in Debian's ``chromium --headless`` and drives the page over the
Chrome DevTools Protocol (a websocket; ``websockets`` is in the dev extra). There is no GPU here:
WebGL runs on SwiftShader (``--use-angle=swiftshader --enable-unsafe-swiftshader``) and the URL
asks the viewer for WebGL (``renderer=webgl``): WebGPU finds no Vulkan driver in a headless
sandbox. The viewer draws into one canvas (egui), so what it shows can only be read from pixels:
:meth:`WebViewer.wait_for` polls screenshots until a predicate holds, within a deadline.

Every wait is bounded and says what it saw when it gives up; both processes are started in
their own process group and that group is ended on close.
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.parse
import urllib.request
from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import Image
from websockets.sync.client import connect

from services.logger.rerun_server import end_group, rerun_binary
from shared.bus import free_port

#: Debian's package; `make test-browser` installs it when missing.
CHROMIUM = os.environ.get("MIMIC_CHROMIUM", "chromium")
#: Software WebGL in a headless browser without a GPU or a display.
CHROMIUM_FLAGS = (
    "--headless=new",
    "--no-sandbox",  # CI runs as root, where Chromium's sandbox refuses to start
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--ignore-gpu-blocklist",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-extensions",
    "--disable-background-networking",
    "--disable-component-update",
    "--mute-audio",
)


class ViewerError(AssertionError):
    """The viewer did not get where a test waited for it to get (with what was seen instead)."""


def chromium_path() -> str | None:
    """Path of the Chromium binary, None when it is not installed."""
    return shutil.which(CHROMIUM)


class WebViewer:
    """One recording in the Rerun web viewer in headless Chromium.

    Args:
        rrd: the recording to open.
        size: page (width, height) [CSS px]; the screenshots have this size.
        workdir: where Chromium's profile and the server logs go (a temporary folder if None).

    Use as a context manager; :meth:`open` waits (up to ``timeout`` [s]) for the viewer's
    application to start, :meth:`wait_for` for what it draws.
    """

    def __init__(self, rrd: Path, size: tuple[int, int] = (1024, 640), workdir: Path | None = None):
        self.rrd = Path(rrd)
        self.size = size
        self.workdir = Path(workdir or tempfile.mkdtemp(prefix="mimic-webviewer-"))
        self.web_port, self.grpc_port = free_port(), free_port()
        self._procs: list[subprocess.Popen] = []
        self._ws = None
        self._exit = contextlib.ExitStack()
        self._id = 0
        self.t_start = time.monotonic()
        self.t_app = float("nan")  # seconds from start to the viewer's application running
        self.t_drawn = float("nan")  # seconds from start to the first screenshot :meth:`wait_for` accepted

    # ------------------------------------------------------------------ processes

    def _spawn(self, argv: list[str], log_name: str) -> None:
        """Start ``argv`` in a process group of its own, output to ``workdir/log_name``."""
        with open(self.workdir / log_name, "w") as out:  # the child keeps its own descriptor
            self._procs.append(subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, start_new_session=True))

    def __enter__(self) -> WebViewer:
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.t_start = time.monotonic()
        ports = ["--web-viewer-port", str(self.web_port), "--port", str(self.grpc_port)]
        self._spawn([rerun_binary(), "--serve-web", str(self.rrd), "--bind", "127.0.0.1", *ports], "rerun.log")
        profile = self.workdir / "chromium-profile"
        window = f"--window-size={self.size[0]},{self.size[1]}"
        browser = chromium_path() or CHROMIUM
        self._spawn(
            [
                browser,
                *CHROMIUM_FLAGS,
                f"--user-data-dir={profile}",
                "--remote-debugging-port=0",
                window,
                "about:blank",
            ],
            "chromium.log",
        )
        return self

    def __exit__(self, *exc) -> None:
        try:
            self._exit.close()  # the DevTools websocket
        except Exception:
            pass
        for p in reversed(self._procs):
            end_group(p)

    def _log_tail(self, name: str, n: int = 5) -> str:
        try:
            return " | ".join((self.workdir / name).read_text(errors="replace").strip().splitlines()[-n:])
        except OSError:
            return "(no log)"

    def _alive(self, what: str) -> None:
        for p, name in zip(self._procs, ("rerun.log", "chromium.log")):
            if p.poll() is not None:
                raise ViewerError(f"{what}: {Path(p.args[0]).name} exited with {p.returncode}: {self._log_tail(name)}")

    def _until(self, what: str, deadline: float, probe: Callable[[], object], period: float = 0.2):
        """Call ``probe`` until it returns a truthy value; ViewerError at ``deadline`` (monotonic)."""
        while True:
            self._alive(what)
            got = probe()
            if got:
                return got
            if time.monotonic() > deadline:
                raise ViewerError(f"{what}: not within {deadline - self.t_start:.0f} s of the start")
            time.sleep(period)

    # ------------------------------------------------------------------ DevTools protocol

    def _call(self, method: str, timeout: float, **params) -> dict:
        """One DevTools command; its ``result`` (events in between are skipped)."""
        self._id += 1
        self._ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                raise ViewerError(f"{method}: no answer from Chromium within {timeout:.0f} s")
            try:
                msg = json.loads(self._ws.recv(timeout=left))
            except TimeoutError:
                continue
            if msg.get("id") == self._id:
                if "error" in msg:
                    raise ViewerError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    def _evaluate(self, expression: str, timeout: float = 30.0):
        res = self._call("Runtime.evaluate", timeout, expression=expression, returnByValue=True)
        return res.get("result", {}).get("value")

    def url(self) -> str:
        """The viewer page, told to read the served recording, to render with WebGL, and to take its examples
        list from an empty inline manifest: by default it fetches one from app.rerun.io, which fails offline and
        puts a toast with an orange icon over the time-series column at a moment no screenshot can predict."""
        data = f"rerun+http://127.0.0.1:{self.grpc_port}/proxy"
        query = {"url": data, "renderer": "webgl", "manifest_url": "data:application/json,[]"}
        return f"http://127.0.0.1:{self.web_port}/?" + urllib.parse.urlencode(query)

    def open(self, timeout: float) -> None:
        """Connect to Chromium, load the viewer and wait for its application to run (``timeout`` [s])."""
        deadline = self.t_start + timeout
        port_file = self.workdir / "chromium-profile" / "DevToolsActivePort"

        def devtools_port() -> int | None:
            text = port_file.read_text() if port_file.exists() else ""
            return int(text.split()[0]) if text.strip() else None

        def viewer_served() -> bool:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{self.web_port}/", timeout=2) as r:
                    return r.status == 200
            except OSError:
                return False

        port = self._until("Chromium's DevTools port", deadline, devtools_port)
        self._until(f"the web viewer on port {self.web_port}", deadline, viewer_served)
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=10) as r:
            page = next(t for t in json.load(r) if t["type"] == "page")
        self._ws = self._exit.enter_context(connect(page["webSocketDebuggerUrl"], max_size=1 << 28, open_timeout=30))
        # The page gets exactly ``size`` (the window also holds the headless browser's own bars), and the
        # viewer follows the system theme: both fixed, so pixels mean the same on every machine.
        w, h = self.size
        self._call("Emulation.setDeviceMetricsOverride", 30, width=w, height=h, deviceScaleFactor=1, mobile=False)
        self._call("Emulation.setEmulatedMedia", 30, features=[{"name": "prefers-color-scheme", "value": "light"}])
        self._call("Page.navigate", 60, url=self.url())
        # index.html sets window._handle once the wasm application has started; until then it
        # shows "Loading Application Bundle…" (or an error) in #center_text.
        status = "window._handle ? 'started' : (document.getElementById('center_text') || {}).innerText || ''"
        last = [""]

        def started() -> bool:
            last[0] = self._evaluate(status) or ""
            if "error" in last[0].lower() or "crashed" in last[0].lower():
                raise ViewerError(f"the web viewer failed: {last[0].strip()}")
            return last[0] == "started"

        try:
            self._until("the web viewer application", deadline, started, period=0.5)
        except ViewerError as exc:
            raise ViewerError(f"{exc}; the page said {last[0].strip()!r}") from None
        self.t_app = time.monotonic() - self.t_start

    def screenshot(self, timeout: float = 120.0) -> np.ndarray:
        """The page as drawn now: (H, W, 3) uint8 RGB."""
        res = self._call("Page.captureScreenshot", timeout, format="png")
        return np.asarray(Image.open(io.BytesIO(base64.b64decode(res["data"]))).convert("RGB"))

    def wait_for(
        self, what: str, ready: Callable[[np.ndarray], bool], timeout: float, save: Path | None = None
    ) -> np.ndarray:
        """Screenshots until ``ready(img)``; the first such image. ViewerError (last one saved) at the deadline."""
        deadline = self.t_start + timeout
        img = None
        while True:
            self._alive(what)
            img = self.screenshot(timeout=max(5.0, deadline - time.monotonic()))
            if save is not None:
                Image.fromarray(img).save(save)
            if ready(img):
                self.t_drawn = time.monotonic() - self.t_start
                return img
            if time.monotonic() > deadline:
                raise ViewerError(
                    f"{what}: not drawn within {timeout:.0f} s (application up after {self.t_app:.0f} s)"
                    + (f"; last screenshot: {save}" if save else "")
                )
            time.sleep(1.0)
