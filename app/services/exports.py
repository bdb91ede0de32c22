"""Exports: constraint pairs and labelled samples (JSON lines or `.npz` with the sample arrays),
and per-frame SemanticKITTI `.label` files streamed as a tar archive (a class for every point, with its
source: app/services/point_labels.py).

Track ids are written as SemanticKITTI instance ids (16 bits). When a sequence's track ids exceed
65,535, frames are cut into chunks whose labelled tracks are renumbered densely from 1, and
`chunk_map.json` records `(chunk, local id) -> global track id` (docs/conventions.md).
"""

from __future__ import annotations

import io
import json
import math
import tarfile
from collections import defaultdict
from collections.abc import Iterator
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import ArtifactStore
from app.models import Frame, Segment
from app.services.point_labels import FrameLabels, LabelSummary, PointLabelPlan, TrackRow, iter_frame_labels

MAX_INSTANCE = 0xFFFF
_IN_CHUNK = 5000


def constraint_rows(session: Session, sequence_id: int | None, verified_only: bool) -> list[dict[str, Any]]:
    rows = session.execute(crud.constraints_query(sequence_id, verified_only)).all()
    return [
        {
            "id": r.id,
            "track_id": r.track_id,
            "segment_a": r.segment_a_id,
            "segment_b": r.segment_b_id,
            "frame_a": r.frame_a,
            "frame_b": r.frame_b,
            "score": r.score,
            "verified": bool(r.verified),
        }
        for r in rows
    ]


_CONSTRAINT_LINE = (
    '{"id": %d, "track_id": %d, "segment_a": %d, "segment_b": %d, "frame_a": %d, "frame_b": %d, '
    '"score": %s, "verified": %s}\n'
)


def constraint_lines(session: Session, sequence_id: int | None, verified_only: bool) -> list[tuple]:
    """The constraint rows as plain tuples (id, track, segment a, segment b, frame a, frame b,
    score, verified), for `constraints_jsonl`: no dict per row."""
    return [tuple(r) for r in session.connection().execute(crud.constraints_query(sequence_id, verified_only))]


def constraints_jsonl(rows: list[tuple], chunk_rows: int = 0) -> Iterator[bytes]:
    """The JSON lines of `constraint_rows` (same keys, same values), formatted from tuples in
    chunks: a dict and a `json.dumps` per row cost twice the query (bench/bench_service.py)."""
    chunk_rows = chunk_rows or JSONL_CHUNK_ROWS
    line = _CONSTRAINT_LINE
    for i in range(0, len(rows), chunk_rows):
        yield "".join([
            line % (a, t, sa, sb, fa, fb, _json_float(sc), "true" if v else "false")
            for a, t, sa, sb, fa, fb, sc, v in rows[i : i + chunk_rows]
        ]).encode()


def _json_float(value: float | None) -> str:
    return repr(float(value)) if value is not None and math.isfinite(value) else "null"


def label_rows(session: Session, sequence_id: int | None) -> list[dict[str, Any]]:
    return [
        {
            "segment_id": r.segment_id,
            "track_id": r.track_id,
            "frame_index": r.frame_index,
            "class": r.class_name,
            "class_index": r.class_index,
        }
        for r in session.execute(crud.labels_query(sequence_id)).all()
    ]


JSONL_CHUNK_ROWS = 2000  # one streamed chunk: ~200 kB; a chunk per row cost ~0.2 ms of ASGI each


def jsonl(rows: list[dict[str, Any]], chunk_rows: int = JSONL_CHUNK_ROWS) -> Iterator[bytes]:
    """JSON lines, `chunk_rows` rows a chunk."""
    dumps = json.JSONEncoder(separators=(", ", ": ")).encode
    for i in range(0, len(rows), chunk_rows):
        yield "".join([dumps(r) + "\n" for r in rows[i : i + chunk_rows]]).encode()


def load_samples(session: Session, artifacts: ArtifactStore, segment_ids: list[int]) -> np.ndarray:
    """(M, C, S, S) uint8 samples of `segment_ids` in that order (every id must have a sample)."""
    where: dict[int, tuple[str, int]] = {}
    for i in range(0, len(segment_ids), _IN_CHUNK):
        chunk = segment_ids[i : i + _IN_CHUNK]
        for sid, sidx, art in session.execute(
            select(Segment.id, Segment.sample_index, Frame.artifact)
            .join(Frame, Frame.id == Segment.frame_id)
            .where(Segment.id.in_(chunk))
        ).all():
            where[int(sid)] = (art, int(sidx))
    by_file: dict[str, list[tuple[int, int]]] = defaultdict(list)
    for pos, sid in enumerate(segment_ids):
        art, sidx = where[sid]
        by_file[art].append((pos, sidx))
    out: np.ndarray | None = None
    for art, items in by_file.items():
        samples = artifacts.read_arrays(art, ("samples",))["samples"]
        if out is None:
            out = np.zeros((len(segment_ids), *samples.shape[1:]), np.uint8)
        pos, sidx = np.array(items).T
        out[pos] = samples[sidx]
    return out if out is not None else np.zeros((0, 0, 0, 0), np.uint8)


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def constraints_npz(session: Session, artifacts: ArtifactStore, rows: list[dict[str, Any]]) -> bytes:
    """samples (M,C,S,S), sample_segment (M,), pairs (P,2) indices into samples, score (P,),
    verified (P,) bool, track_id (P,)."""
    seg_ids = sorted({r["segment_a"] for r in rows} | {r["segment_b"] for r in rows})
    pos = {s: i for i, s in enumerate(seg_ids)}
    return npz_bytes(
        {
            "samples": load_samples(session, artifacts, seg_ids),
            "sample_segment": np.array(seg_ids, np.int64),
            "pairs": np.array([[pos[r["segment_a"]], pos[r["segment_b"]]] for r in rows], np.int64).reshape(-1, 2),
            "score": np.array([r["score"] for r in rows], np.float32),
            "verified": np.array([r["verified"] for r in rows], bool),
            "track_id": np.array([r["track_id"] for r in rows], np.int64),
        }
    )


def labels_npz(session: Session, artifacts: ArtifactStore, rows: list[dict[str, Any]]) -> bytes:
    """samples (M,C,S,S), label (M,) class index, segment_id, track_id, frame_index (M,)."""
    seg_ids = [r["segment_id"] for r in rows]
    return npz_bytes(
        {
            "samples": load_samples(session, artifacts, seg_ids),
            "label": np.array([r["class_index"] for r in rows], np.int64),
            "segment_id": np.array(seg_ids, np.int64),
            "track_id": np.array([r["track_id"] for r in rows], np.int64),
            "frame_index": np.array([r["frame_index"] for r in rows], np.int64),
        }
    )


def _instances(plan: PointLabelPlan) -> tuple[dict[int, dict[int, int]], list[dict[str, Any]] | None]:
    """Per frame index: db track id -> instance id of the tracks whose points take their class
    (decided or predicted); plus the chunk map when keys need chunking."""
    tracks = [*plan.decided, *plan.predicted]
    per_frame: dict[int, list[TrackRow]] = defaultdict(list)
    for t in tracks:
        for f in range(t.keep_start, t.keep_end + 1):
            per_frame[f].append(t)
    if not tracks or max(t.key for t in tracks) <= MAX_INSTANCE:
        return {f: {t.db_id: t.key for t in ts} for f, ts in per_frame.items()}, None
    out: dict[int, dict[int, int]] = {}
    chunks: list[dict[str, Any]] = []
    local: dict[int, int] = {}
    first: int | None = None
    prev = -1
    for index, *_ in plan.frames:
        keys = {t.key for t in per_frame.get(index, [])}
        if len(local) + len(keys - local.keys()) > MAX_INSTANCE and local:
            chunks.append({"chunk": len(chunks), "frames": [first, prev], "instances": {v: k for k, v in local.items()}})
            local, first = {}, None
        first = index if first is None else first
        for k in sorted(keys - local.keys()):
            local[k] = len(local) + 1
        out[index] = {t.db_id: local[t.key] for t in per_frame.get(index, [])}
        prev = index
    if local:
        chunks.append({"chunk": len(chunks), "frames": [first, prev], "instances": {v: k for k, v in local.items()}})
    return out, chunks


class _Sink(io.RawIOBase):
    def __init__(self) -> None:
        self.parts: list[bytes] = []

    def writable(self) -> bool:
        return True

    def write(self, b: Any) -> int:
        self.parts.append(bytes(b))
        return len(b)

    def drain(self) -> bytes:
        out = b"".join(self.parts)
        self.parts.clear()
        return out


def _add(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size = len(data)
    tar.addfile(info, io.BytesIO(data))


def _spread(values: np.ndarray, input_rows: np.ndarray) -> np.ndarray:
    """(N_input,) `values` (N,) of a frame's points at their input rows, 0 elsewhere."""
    out = np.zeros(len(input_rows), values.dtype)
    out[input_rows] = values
    return out


def _label_words(fl: FrameLabels, instances: dict[int, int], to_semantickitti: np.ndarray) -> np.ndarray:
    """(N,) uint32 SemanticKITTI words of one frame's points: class | instance << 16, the instance
    being the point's own track's where it took that track's class; `to_semantickitti` (256,) is
    the sequence's label set's id per class index."""
    words = to_semantickitti[fl.labels.class_].astype(np.uint32)
    if instances:
        ids = np.array(sorted(instances), np.int64)
        pos = np.minimum(np.searchsorted(ids, fl.track), len(ids) - 1)
        hit = (ids[pos] == fl.track) & fl.from_track
        ins = np.array([instances[i] for i in ids], np.uint32)
        words[hit] |= ins[pos[hit]] << 16
    return words


def semantickitti_tar(plan: PointLabelPlan, artifacts: ArtifactStore, with_sources: bool = False) -> Iterator[bytes]:
    """Stream `sequences/<name>/labels/<frame>.label` (uint32: semantic | instance << 16) per frame,
    one label per row of the frame's scan file (0 for rows that are no point: NaN, inf, no return),
    then `summary.json`: the points per label source and class, confidence histograms, and why
    points stayed unlabelled (app/services/point_labels.py). `with_sources` adds
    `sources/<frame>.source`: one uint8 per row, the index of its source in `summary.sources`."""
    to_semantickitti = plan.label_set.to_semantickitti_table()
    instances, chunk_map = _instances(plan)
    summary = LabelSummary()
    sink = _Sink()
    tar = tarfile.open(fileobj=sink, mode="w|")
    prefix = f"sequences/{plan.sequence_name}"
    for fl in iter_frame_labels(plan, artifacts):
        summary.add(fl)
        words = _label_words(fl, instances.get(fl.index, {}), to_semantickitti)
        sources = fl.labels.source
        if fl.input_rows is not None:
            words, sources = _spread(words, fl.input_rows), _spread(sources, fl.input_rows)
        _add(tar, f"{prefix}/labels/{fl.name}.label", words.tobytes())
        if with_sources:
            _add(tar, f"{prefix}/sources/{fl.name}.source", sources.tobytes())
        yield sink.drain()
    if chunk_map is not None:
        _add(tar, f"{prefix}/chunk_map.json", json.dumps({"chunks": chunk_map}, indent=1).encode())
    _add(tar, f"{prefix}/summary.json", json.dumps(summary.to_dict(plan.options, plan.label_set), indent=1).encode())
    tar.close()
    yield sink.drain()
