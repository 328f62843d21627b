"""Skeleton maps: rig joint names -> canonical bones (``HUMAN_BONES``).

A map gives, per canonical bone, candidate joint names tried in order (first
present wins). ``"<joint>/end"`` names the End Site of ``<joint>`` (used for
the hand tip). Names match case-insensitively and without a namespace prefix
(``mixamorig:LeftArm`` matches ``LeftArm``). ``hips`` names the left and right
hip joints, used only to orient the pelvis frame (y axis from right to left hip).

User map file (``--skeleton-map FILE``), TOML or JSON with the same keys::

    name = "my_rig"
    [bones]                      # canonical bone -> joint name or list of candidates
    pelvis = "Hips"
    left_shoulder = "L_UpperArm"  # the shoulder *joint* (upper-arm bone origin)
    left_elbow = "L_Forearm"
    left_wrist = "L_Hand"
    left_hand = "L_Hand/end"      # hand tip: End Site of L_Hand
    # ... right_*, spine, chest, neck, head, *_clavicle (optional)
    [hips]                       # optional; else the shoulders orient the pelvis
    left = "L_Thigh"
    right = "R_Thigh"

An optional ``namespace`` (e.g. ``"mixamorig"``) breaks ties between maps that fit equally well.
The built-in maps are written in this format in ``skeleton_maps.toml``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from services.ingest.errors import SkeletonMapError
from services.ingest.map_files import name_list, read_map_file
from shared.messages import HUMAN_BONES

#: Bones a rig must provide; the others are optional (flagged invalid when absent).
REQUIRED_BONES: tuple[str, ...] = (
    "pelvis",
    *(f"{s}_{b}" for s in ("left", "right") for b in ("shoulder", "elbow", "wrist")),
)


def _norm(name: str) -> str:
    return name.rsplit(":", 1)[-1].strip().lower()


@dataclass(frozen=True)
class SkeletonMap:
    """Canonical bone -> candidate rig joint names.

    Attributes:
        name: map name (reported in the clip metadata).
        bones: canonical bone -> candidates, first present wins; ``"J/end"`` is J's End Site.
        hips: ("left" | "right") -> candidates for the hip joints orienting the pelvis frame.
        namespace: joint-name namespace typical of the rig (``mixamorig`` for
            ``mixamorig:Hips``); breaks ties between maps that fit equally well.
    """

    name: str
    bones: dict[str, tuple[str, ...]]
    hips: dict[str, tuple[str, ...]] = field(default_factory=dict)
    namespace: str = ""

    def resolve(self, joints: list[str], end_sites: set[str]) -> tuple[dict[str, str], dict[str, str]]:
        """Match this map against a rig.

        Args:
            joints: rig joint names (original spelling).
            end_sites: names of the joints that have an End Site.

        Returns:
            (bones, hips): canonical bone -> resolved spec (``"Joint"`` or
            ``"Joint/end"`` with the rig's spelling), and side -> hip joint.
        """
        by_norm: dict[str, str] = {}
        for j in joints:
            by_norm.setdefault(_norm(j), j)

        def find(cands: tuple[str, ...]) -> str | None:
            for c in cands:
                base, _, tail = c.partition("/")
                j = by_norm.get(_norm(base))
                if j is None:
                    continue
                if tail == "end":
                    if j in end_sites:
                        return f"{j}/end"
                    continue
                return j
            return None

        bones = {b: s for b, c in self.bones.items() if (s := find(c)) is not None}
        hips = {side: s for side, c in self.hips.items() if (s := find(c)) is not None and "/" not in s}
        return bones, hips


def map_from_table(data: dict, default_name: str, where: str) -> SkeletonMap:
    """A skeleton map from its table (the map file format in the module docstring).

    Args:
        default_name: the name when the table gives none.
        where: what to name in errors (the file, and the map's table in it).

    Raises:
        SkeletonMapError: unknown canonical names, wrong types.
    """

    def cands(v, key) -> tuple[str, ...]:
        return name_list(v, f"skeleton map {where}: {key} must be a joint name", SkeletonMapError)

    raw = data.get("bones")
    if not isinstance(raw, dict) or not raw:
        raise SkeletonMapError(f"skeleton map {where}: missing [bones] table (canonical bone -> joint name)")
    unknown = [b for b in raw if b not in HUMAN_BONES]
    if unknown:
        raise SkeletonMapError(f"skeleton map {where}: unknown canonical bones {unknown}; known: {list(HUMAN_BONES)}")
    hips_raw = data.get("hips", {})
    if not isinstance(hips_raw, dict) or set(hips_raw) - {"left", "right"}:
        raise SkeletonMapError(f"skeleton map {where}: [hips] takes only 'left' and 'right'")
    namespace = data.get("namespace", "")
    if not isinstance(namespace, str):
        raise SkeletonMapError(f"skeleton map {where}: namespace must be a text")
    return SkeletonMap(
        str(data.get("name", default_name)),
        {b: cands(v, f"bones.{b}") for b, v in raw.items()},
        {s: cands(v, f"hips.{s}") for s, v in hips_raw.items()},
        namespace=namespace,
    )


#: The built-in maps' file (the user map format, one table per map, in detection order).
BUILTIN_MAP_FILE = Path(__file__).with_name("skeleton_maps.toml")


def _builtin_maps() -> tuple[SkeletonMap, ...]:
    tables = read_map_file(BUILTIN_MAP_FILE, "skeleton map", SkeletonMapError)
    return tuple(map_from_table(t, name, f"{BUILTIN_MAP_FILE} [{name}]") for name, t in tables.items())


BUILTIN_MAPS: tuple[SkeletonMap, ...] = _builtin_maps()


def detect_map(
    joints: list[str], end_sites: set[str], source: str = "", maps: tuple[SkeletonMap, ...] = BUILTIN_MAPS
) -> tuple[SkeletonMap, dict[str, str], dict[str, str]]:
    """Pick the map that fits the rig best (most canonical bones, all required ones).

    Raises:
        SkeletonMapError: no map provides every required bone; the text lists the
            rig's joints and the canonical bones that could not be mapped.
    """
    best = None
    for m in maps:
        bones, hips = m.resolve(joints, end_sites)
        complete = all(b in bones for b in REQUIRED_BONES)
        ns = bool(m.namespace) and any(j.split(":", 1)[0].lower().startswith(m.namespace) for j in joints if ":" in j)
        score = (complete, len(bones) + len(hips), ns)
        if best is None or score > best[0]:
            best = (score, m, bones, hips)
    assert best is not None
    (complete, _, _), m, bones, hips = best
    if not complete:
        missing = [b for b in REQUIRED_BONES if b not in bones]
        optional = [b for b in HUMAN_BONES if b not in bones and b not in REQUIRED_BONES]
        raise SkeletonMapError(
            f"unknown skeleton{' in ' + source if source else ''}: no "
            f"{'built-in ' if len(maps) > 1 else ''}map ({', '.join(x.name for x in maps)}) maps the required bones. "
            f"Closest: '{m.name}', which could not map canonical bones {missing}"
            f"{f' (optional ones also unmapped: {optional})' if optional else ''}. "
            f"Bones found in the file: {list(joints)}. "
            "Pass --skeleton-map FILE (TOML/JSON, format in services/ingest/README.md)."
        )
    return m, bones, hips


def load_skeleton_map(path: str | Path) -> SkeletonMap:
    """Read a user skeleton map (TOML or JSON; format in the module docstring).

    Raises:
        SkeletonMapError: unreadable file, unknown canonical names, wrong types.
    """
    path = Path(path)
    return map_from_table(read_map_file(path, "skeleton map", SkeletonMapError), path.stem, str(path))
