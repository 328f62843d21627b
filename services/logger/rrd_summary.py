"""Read a recorded ``.rrd`` back with Rerun's own reader (``rerun.chunk.RrdReader``).

Rerun 0.41 has no ``rr.dataframe``; its replacement is the chunk API: an
:class:`~rerun.chunk.RrdReader` streams the chunks of the file's recording store,
each an Arrow record batch for one entity (index columns ``seq``, ``stamp``,
``log_time``, plus one column per component). That needs no extra package
(the DataFusion query layer, ``ChunkStore.reader``, would need ``datafusion``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rerun.chunk import RrdReader


@dataclass
class RrdSummary:
    """Rows per entity path of one recording.

    Attributes:
        rows: entity path (leading "/") -> temporal rows.
        static: entity path -> static rows.
        timelines: entity path -> timelines its temporal rows are indexed on.
        chunks: number of chunks read.
    """

    rows: dict[str, int] = field(default_factory=dict)
    static: dict[str, int] = field(default_factory=dict)
    timelines: dict[str, set[str]] = field(default_factory=dict)
    chunks: int = 0


def _chunks(path: Path):
    return RrdReader(str(path)).stream().collect().stream()


def summarize(path: str | Path) -> RrdSummary:
    """Entity paths, row counts and timelines of the first recording in ``path``."""
    out = RrdSummary()
    for ch in _chunks(Path(path)):
        out.chunks += 1
        ent = ch.entity_path
        if ch.is_static:
            out.static[ent] = out.static.get(ent, 0) + ch.num_rows
        else:
            out.rows[ent] = out.rows.get(ent, 0) + ch.num_rows
            out.timelines.setdefault(ent, set()).update(ch.timeline_names)
    return out


def scalar_rows(path: str | Path, entity: str, timeline: str = "seq") -> tuple[np.ndarray, np.ndarray]:
    """(index (m,), values (m, k)) of a Scalars entity, sorted by ``timeline``.

    Args:
        entity: entity path, with or without the leading "/".
        timeline: index column to return ("seq" int, "stamp" [s]).
    """
    entity = entity if entity.startswith("/") else "/" + entity
    idx: list = []
    vals: list = []
    for ch in _chunks(Path(path)):
        if ch.entity_path != entity or ch.is_static:
            continue
        rb = ch.to_record_batch()
        names = rb.schema.names
        col = next((n for n in names if n.endswith(":scalars")), None)
        if col is None or timeline not in names:
            continue
        t = rb.column(names.index(timeline))
        t = t.cast("int64").to_numpy() if timeline != "stamp" else t.cast("int64").to_numpy() * 1e-9
        idx.extend(t.tolist())
        vals.extend(rb.column(names.index(col)).to_pylist())
    if not idx:
        return np.zeros(0), np.zeros((0, 0))
    order = np.argsort(idx, kind="stable")
    return np.asarray(idx)[order], np.asarray(vals, dtype=float)[order]
