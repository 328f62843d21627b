"""One stack per session and working directory: ``runs/<session>.lock`` holds the owner's pid.

Two stacks of one session would share every key on the bus and every state file
(``runs/<session>_calibration.json``, the recording): the second would delete the
first one's calibration and interleave its frames. :class:`SessionLock` is taken before
a stack touches any file and released when it stops; a lock whose process is gone (a
killed stack) is taken over.
"""

from __future__ import annotations

import os
from pathlib import Path


class SessionBusyError(RuntimeError):
    """Another live stack holds the session."""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


class SessionLock:
    """Exclusive claim of ``session`` in ``run_dir`` by this process.

    Args:
        run_dir: folder of the session's files (``runs/``).
        session: session name.
    """

    def __init__(self, run_dir: Path, session: str):
        self.path = Path(run_dir) / f"{session}.lock"
        self.session = session
        self.held = False

    def owner(self) -> int | None:
        """pid of the live process holding the lock (None: free or stale)."""
        try:
            pid = int(self.path.read_text().split()[0])
        except (OSError, ValueError, IndexError):
            return None
        return pid if _alive(pid) else None

    def acquire(self) -> None:
        """Take the lock.

        Raises:
            SessionBusyError: a live process holds it (one line, naming the pid and the way out).
        """
        self.path.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                pid = self.owner()
                if pid is not None:
                    raise SessionBusyError(
                        f"session {self.session!r} is already run by a live stack (pid {pid}, {self.path}): "
                        "stop it, or run beside it with another --session and --endpoint (mimic up --beside)"
                    ) from None
                self.path.unlink(missing_ok=True)  # stale: its stack died without releasing it
                continue
            with os.fdopen(fd, "w") as f:
                f.write(f"{os.getpid()}\n")
            self.held = True
            return
        raise SessionBusyError(f"cannot take {self.path}: another stack is starting on session {self.session!r}")

    def release(self) -> None:
        """Give the lock back (only if this process holds it)."""
        if self.held:
            self.path.unlink(missing_ok=True)
            self.held = False
