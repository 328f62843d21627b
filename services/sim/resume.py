"""The sim's last state on disk, so a restarted sim resumes where the robot was.

A sim that crashes and comes back (``mimic up --restart``) would otherwise start at the
profile rest pose: the simulated robot jumps (1.88 rad was seen) and the solver, which
starts from the measured state, follows the jump. The node writes the joint positions
(JSON ``{"joints": [...], "q": [...]}``, radians) atomically a few times a second; a new
sim loads them when the file exists. ``mimic up`` deletes the file when a stack starts and
when it stops (a new stack starts at rest); its restarts keep it.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np

log = logging.getLogger("mimic.sim")


def session_state_file(session: str) -> str:
    """Default state file of a session's sim, relative to the working directory."""
    return f"runs/{session}_sim_state.json"


def save_state(path: Path, joints: list[str], q: np.ndarray) -> None:
    """Write ``q`` (n,) [rad] of ``joints`` to ``path`` atomically (a crash never leaves half a file)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps({"joints": list(joints), "q": [float(x) for x in q]}))
    os.replace(tmp, path)


def load_state(path: Path, joints: list[str]) -> np.ndarray | None:
    """Joint positions (n,) [rad] in the order of ``joints`` from ``path``; None when absent or unusable
    (logged: a bad file must not keep the sim down)."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        d = json.loads(path.read_text())
        by_name = dict(zip(d["joints"], d["q"], strict=True))
        q = np.array([float(by_name[n]) for n in joints])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        log.warning("ignoring the sim state file %s: %s", path, exc)
        return None
    if not np.all(np.isfinite(q)):
        log.warning("ignoring the sim state file %s: non-finite positions", path)
        return None
    return q
