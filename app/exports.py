"""Exports: constraint pairs and labelled samples (JSON lines or `.npz` with the sample arrays),
and per-frame SemanticKITTI `.label` files streamed as a tar archive.

Track ids are written as SemanticKITTI instance ids (16 bits). When a sequence's track ids exceed
65,535, frames are cut into chunks whose labelled tracks are renumbered densely from 1, and
`chunk_map.json` records `(chunk, local id) -> global track id` (docs/conventions.md).
"""

from __future__ import annotations

import io
import json
import tarfile
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import ArtifactStore
from app.models import Frame, Segment, Sequence

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


@dataclass(frozen=True)
class _LabelledTrack:
    db_id: int
    key: int
    semantic: int
    keep_start: int
    keep_end: int


@dataclass(frozen=True)
class SemanticKittiPlan:
    """Everything the archive needs, read from the database before streaming starts."""

    sequence_name: str
    frames: list[tuple[int, str, str]]  # (index, name, artifact)
    tracks: list[_LabelledTrack]
    include_ground: bool


def semantickitti_plan(session: Session, sequence: Sequence, include_ground: bool) -> SemanticKittiPlan:
    from pipeline.classes import CLASS_INDEX, to_semantickitti

    frames = [
        (int(i), str(n), str(a))
        for i, n, a in session.execute(
            select(Frame.index, Frame.name, Frame.artifact).where(Frame.sequence_id == sequence.id).order_by(Frame.index)
        ).all()
    ]
    tracks = [
        _LabelledTrack(
            int(r.id), int(r.key), int(to_semantickitti(np.array([CLASS_INDEX[r.label]]))[0]), int(r.keep_start), int(r.keep_end)
        )
        for r in crud.track_label_rows(session, sequence.id)
    ]
    return SemanticKittiPlan(sequence.name, frames, tracks, include_ground)


def _instances(plan: SemanticKittiPlan) -> tuple[dict[int, dict[int, int]], list[dict[str, Any]] | None]:
    """Per frame index: db track id -> instance id; plus the chunk map when ids need chunking."""
    per_frame: dict[int, list[_LabelledTrack]] = defaultdict(list)
    for t in plan.tracks:
        for f in range(t.keep_start, t.keep_end + 1):
            per_frame[f].append(t)
    if not plan.tracks or max(t.key for t in plan.tracks) <= MAX_INSTANCE:
        return {f: {t.db_id: t.key for t in ts} for f, ts in per_frame.items()}, None
    out: dict[int, dict[int, int]] = {}
    chunks: list[dict[str, Any]] = []
    local: dict[int, int] = {}
    first: int | None = None
    prev = -1
    for index, _name, _art in plan.frames:
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


def semantickitti_tar(plan: SemanticKittiPlan, artifacts: ArtifactStore) -> Iterator[bytes]:
    """Stream `sequences/<name>/labels/<frame>.label` (uint32: semantic | instance << 16) per frame,
    one label per row of the frame's scan file (0 for rows that are no point: NaN, inf, no return)."""
    from pipeline.classes import SEMANTICKITTI_WRITE_ID

    instances, chunk_map = _instances(plan)
    sem_of = {t.db_id: t.semantic for t in plan.tracks}
    ground_id = SEMANTICKITTI_WRITE_ID["ground"]
    sink = _Sink()
    tar = tarfile.open(fileobj=sink, mode="w|")
    prefix = f"sequences/{plan.sequence_name}"
    for index, name, art in plan.frames:
        a = artifacts.read_arrays(art, ("track", "ground", "input_rows"))
        track = a["track"]
        label = np.zeros(len(track), np.uint32)
        if plan.include_ground:
            label[a["ground"]] = ground_id
        inst = instances.get(index, {})
        if inst:
            ids = np.array(sorted(inst), np.int64)
            pos = np.searchsorted(ids, track)
            pos = np.minimum(pos, len(ids) - 1)
            hit = (ids[pos] == track) & (track > 0)
            sem = np.array([sem_of[i] for i in ids], np.uint32)
            ins = np.array([inst[i] for i in ids], np.uint32)
            label[hit] = sem[pos[hit]] | (ins[pos[hit]] << 16)
        rows = a.get("input_rows")
        if rows is not None:
            label = _spread(label, rows)
        _add(tar, f"{prefix}/labels/{name}.label", label.tobytes())
        yield sink.drain()
    if chunk_map is not None:
        _add(tar, f"{prefix}/chunk_map.json", json.dumps({"chunks": chunk_map}, indent=1).encode())
    tar.close()
    yield sink.drain()
