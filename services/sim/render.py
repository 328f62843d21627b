"""Optional offscreen rendering of the simulation to MP4 or PNG frames.

MuJoCo picks its OpenGL backend from ``MUJOCO_GL`` when it is first imported
(``egl`` or ``osmesa`` work without a display); :mod:`services.sim.cli` sets
``egl`` by default before importing MuJoCo. Where no backend can create a
context, :func:`open_renderer` returns None with a clear reason and the
simulation runs on without video.

MP4 needs the ``ffmpeg`` program (Debian package ``ffmpeg``) on PATH; without it,
frames are written as numbered PNGs (Pillow).
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import threading
from pathlib import Path

import mujoco
import numpy as np

log = logging.getLogger("mimic.sim.render")

#: What to install when no GL backend works (Debian package names).
GL_HINT = (
    "offscreen rendering needs an OpenGL backend without a display: MUJOCO_GL=egl "
    "(Debian packages libegl1 libegl-mesa0) or MUJOCO_GL=osmesa (Debian package libosmesa6)"
)


class FrameWriter:
    """Renders ``data`` from a fixed free camera at ``fps`` (simulated time) into ``out_dir``.

    Args:
        model: MuJoCo model. out_dir: output folder (created).
        fps: frames per simulated second. width, height: image size [px].
        fmt: "mp4", "png" or "auto" (mp4 when ffmpeg exists).
        lookat: (3,) camera target in the world [m].
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        out_dir: Path,
        fps: float = 30.0,
        width: int = 640,
        height: int = 480,
        fmt: str = "auto",
        lookat: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ):
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, height)
        self.renderer = mujoco.Renderer(model, height, width)
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.fps = fps
        self.width, self.height = width, height
        self.frames = 0
        self._next_t = 0.0
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self.camera.lookat[:] = lookat
        self.camera.distance = 2.4
        self.camera.azimuth = 160.0
        self.camera.elevation = -15.0
        ffmpeg = shutil.which("ffmpeg")
        if fmt == "auto":
            fmt = "mp4" if ffmpeg else "png"
        if fmt == "mp4" and not ffmpeg:
            log.warning("no ffmpeg on PATH (Debian package ffmpeg): writing PNG frames instead of MP4")
            fmt = "png"
        self.fmt = fmt
        self._proc: subprocess.Popen | None = None
        if fmt == "mp4":
            self.path = self.out_dir / "sim.mp4"
            cmd = [ffmpeg, "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24"]
            cmd += ["-s", f"{width}x{height}", "-r", f"{fps:g}", "-i", "-", "-pix_fmt", "yuv420p", str(self.path)]
            self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE)
        else:
            self.path = self.out_dir
        log.info("rendering %dx%d at %g fps to %s (%s)", width, height, fps, self.path, fmt)

    def maybe_render(self, data: mujoco.MjData) -> bool:
        """Render one frame if simulated time reached the next frame time."""
        if data.time + 1e-9 < self._next_t:
            return False
        self._next_t = data.time + 1.0 / self.fps
        self.renderer.update_scene(data, camera=self.camera)
        img = self.renderer.render()
        self.write(img)
        return True

    def write(self, img: np.ndarray) -> None:
        """Append one (height, width, 3) uint8 image."""
        if self._proc is not None and self._proc.stdin is not None:
            self._proc.stdin.write(np.ascontiguousarray(img, dtype=np.uint8).tobytes())
        else:
            from PIL import Image

            Image.fromarray(img).save(self.out_dir / f"frame_{self.frames:06d}.png")
        self.frames += 1

    def close(self) -> None:
        """Finish the video file and free the GL context."""
        if self._proc is not None:
            if self._proc.stdin is not None:
                self._proc.stdin.close()
            self._proc.wait(timeout=30)
            self._proc = None
        self.renderer.close()
        log.info("rendered %d frames to %s", self.frames, self.path)


class BackgroundFrameWriter:
    """A :class:`FrameWriter` in its own thread, fed with pose snapshots.

    Software GL renders a frame in ~0.1-0.2 s on a CPU-only machine; done inline it
    would stall a real-time physics loop. The loop only copies ``qpos`` (newest
    wins); frames the thread cannot keep up with are skipped and counted. The GL
    context is created, used and freed in the thread (contexts are thread-bound).
    """

    def __init__(self, model: mujoco.MjModel, out_dir: Path, **kwargs):
        self.model = model
        self.fps = float(kwargs.get("fps", 30.0))
        self.skipped = 0
        self.frames = 0
        self._next_t = 0.0
        self._cond = threading.Condition()
        self._pending: tuple[float, np.ndarray] | None = None
        self._stop = False
        self._ready = threading.Event()
        self.error: str | None = None
        self._thread = threading.Thread(target=self._run, args=(out_dir, kwargs), name="sim-render", daemon=True)
        self._thread.start()
        self._ready.wait(60.0)
        if self.error is not None:
            self._thread.join(5.0)
            raise RuntimeError(self.error)

    def _run(self, out_dir: Path, kwargs: dict) -> None:
        try:
            writer = FrameWriter(self.model, out_dir, **kwargs)
        except Exception as exc:
            self.error = f"{type(exc).__name__}: {exc}"
            self._ready.set()
            return
        self._ready.set()
        data = mujoco.MjData(self.model)
        try:
            while True:
                with self._cond:
                    while self._pending is None and not self._stop:
                        self._cond.wait()
                    if self._pending is None:
                        return
                    t, qpos = self._pending
                    self._pending = None
                data.qpos[:] = qpos
                data.time = t
                mujoco.mj_forward(self.model, data)
                writer.renderer.update_scene(data, camera=writer.camera)
                writer.write(writer.renderer.render())
                self.frames = writer.frames
        finally:
            writer.close()

    def maybe_render(self, data: mujoco.MjData) -> bool:
        """Hand a snapshot to the thread if a frame is due; never blocks on GL."""
        if data.time + 1e-9 < self._next_t:
            return False
        self._next_t = data.time + 1.0 / self.fps
        with self._cond:
            if self._pending is not None:
                self.skipped += 1
            self._pending = (float(data.time), data.qpos.copy())
            self._cond.notify()
        return True

    def close(self) -> None:
        """Render what is pending, finish the file, free the context."""
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join(60.0)
        if self.skipped:
            log.info("renderer skipped %d frames it could not keep up with", self.skipped)


def open_renderer(
    model: mujoco.MjModel, out_dir: Path, background: bool = False, **kwargs
) -> tuple[FrameWriter | BackgroundFrameWriter | None, str]:
    """A frame writer, or (None, reason) when no GL backend can render here.

    Args:
        background: render in a thread (real-time clock) instead of inline (lock-step,
            where every frame is wanted and time does not run away).
    """
    backend = os.environ.get("MUJOCO_GL", "(unset: glfw, needs a display)")
    try:
        if background:
            return BackgroundFrameWriter(model, out_dir, **kwargs), ""
        return FrameWriter(model, out_dir, **kwargs), ""
    except Exception as exc:  # GL failures surface as several exception types
        reason = f"rendering skipped: MUJOCO_GL={backend} failed ({type(exc).__name__}: {exc}); {GL_HINT}"
        return None, reason
