"""Key expressions live in one module; nowhere else writes a key literal."""

from __future__ import annotations

import re

import pytest

from shared.keys import Keys
from shared.paths import REPO_ROOT

REPO = REPO_ROOT


def test_layout():
    k = Keys("lab1")
    assert k.mocap_frame == "mimic/lab1/mocap/frame"
    assert k.command("shadow") == "mimic/lab1/solver/shadow/command"
    assert Keys.parse_alive(k.alive("sim", "main")) == ("sim", "main")
    assert Keys.session_of(k.targets) == "lab1"


@pytest.mark.parametrize("bad", ["a/b", "", "x*", "sp ace", "$(x)"])
def test_bad_session_rejected(bad):
    with pytest.raises(ValueError, match="one key chunk"):
        Keys(bad)


def test_no_key_literal_outside_keys_module():
    offenders = []
    pattern = re.compile(r"""["']mimic/""")
    for path in list((REPO / "shared").rglob("*.py")) + list((REPO / "services").rglob("*.py")):
        if path.name == "keys.py" and path.parent.name == "shared":
            continue
        for i, line in enumerate(path.read_text().splitlines(), 1):
            if pattern.search(line):
                offenders.append(f"{path.relative_to(REPO)}:{i}: {line.strip()}")
    assert not offenders, "key literals outside shared/keys.py:\n" + "\n".join(offenders)
