"""One live stack per session: the lock file, its refusal, a stale lock taken over."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from services.launcher.session_lock import SessionBusyError, SessionLock


def test_a_live_holder_refuses_a_second_and_a_dead_one_is_taken_over(tmp_path):
    a = SessionLock(tmp_path, "s")
    a.acquire()
    assert (tmp_path / "s.lock").read_text().split()[0] == str(os.getpid())
    with pytest.raises(SessionBusyError, match=r"session 's' is already run by a live stack \(pid \d+"):
        SessionLock(tmp_path, "s").acquire()
    a.release()
    assert not (tmp_path / "s.lock").exists()
    # A stack killed without releasing: its pid is gone, the next stack takes the session.
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    (tmp_path / "s.lock").write_text(dead.stdout)
    b = SessionLock(tmp_path, "s")
    b.acquire()
    assert b.held and (tmp_path / "s.lock").read_text().split()[0] == str(os.getpid())
    b.release()
