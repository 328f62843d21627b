"""Where the repo is, and the one place it reaches outside itself (the mocap data).

The real mocap clips are read at run time from ``MIMIC_MOCAP_DIR``, by default
``../shared/data/mocap`` beside the repo; they are never copied into it.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Root of the repository (the folder holding ``services/``, ``shared/`` and ``models/``).
REPO_ROOT = Path(__file__).resolve().parents[1]
#: Robot profiles (``<name>.toml``).
MODELS_DIR = REPO_ROOT / "models"
#: Environment variable naming the mocap data folder (``bvh/``, ``c3d/``, ``SOURCES.md``).
MOCAP_DIR_ENV = "MIMIC_MOCAP_DIR"


def mocap_dir() -> Path:
    """The mocap data folder: ``$MIMIC_MOCAP_DIR``, or ``../shared/data/mocap`` from the repo root."""
    env = os.environ.get(MOCAP_DIR_ENV)
    return Path(env) if env else (REPO_ROOT.parent / "shared" / "data" / "mocap").resolve()


def unused_path(path: Path) -> Path:
    """``path`` if nothing is there yet, else the first free ``<stem>-<n><suffix>`` (n = 1, 2, ...).

    Recordings and summaries are never overwritten silently: a second run beside the first, or
    the next run of the session, gets a new numbered name.
    """
    path = Path(path)
    if not path.exists():
        return path
    n = 1
    while (candidate := path.with_name(f"{path.stem}-{n}{path.suffix}")).exists():
        n += 1
    return candidate
