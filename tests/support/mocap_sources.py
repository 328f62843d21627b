"""Facts about the real mocap clips, parsed from SOURCES.md beside them (tests never hard-code them)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

#: Heading that starts the part of SOURCES.md documenting the vigorous clips (dash, run, kick, bow).
VIGOROUS_HEADING = "### Added: vigorous motion"


@dataclass(frozen=True)
class MocapSources:
    """SOURCES.md of a mocap folder."""

    text: str

    @classmethod
    def read(cls, mocap_dir: Path) -> MocapSources:
        return cls((mocap_dir / "SOURCES.md").read_text())

    def section(self, name: str) -> str:
        """Text of the entry of ``bvh/<name>`` (``name`` with its ``.bvh``)."""
        return self.text.split(f"`bvh/{name}`", 1)[1].split("####", 1)[0]

    def bvh_names(self, part: str | None = None) -> list[str]:
        """Documented BVH file names: all, or the ``"gestures"`` or the ``"vigorous"`` ones."""
        head, _, tail = self.text.partition(VIGOROUS_HEADING)
        text = {None: self.text, "gestures": head, "vigorous": tail}[part]
        return re.findall(r"^#### `bvh/([^`]+)`", text, re.M)

    def frames(self, name: str) -> int:
        return int(re.search(r"frames: (\d+)", self.section(name)).group(1))

    def pelvis_tilt_over(self) -> tuple[float, set[str]]:
        """(angle [deg], clips) of "a bow tilts the pelvis forward by more than <angle> deg in <clips>"."""
        clips = r"((?:`[^`]+`[,\s]*(?:and\s+)?)+)"
        m = re.search(r"tilts the pelvis forward by more than (\d+) deg in\s+" + clips, self.text)
        return float(m.group(1)), {f"{n}.bvh" for n in re.findall(r"`([^`]+)`", m.group(2))}
