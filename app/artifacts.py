"""Per-frame artifact files: one (partly) compressed `.npz` per frame, next to the database.

A frame row stores the path relative to the artifact root. Layout of a frame file::

    points         (N, 3) float32  lidar frame, metres
    intensity      (N,)   float32  in [0, 1]
    segment        (N,)   int32    local segment id, -1 = ground / none
    ground         (N,)   bool     ground mask
    track          (N,)   int64    database track id of the point's segment, 0 = none
    samples        (V, C, S, S) uint8  the frame's samples (see pipeline/config.py SampleConfig)
    sample_segment (V,)   int32    local segment id of each sample
    input_rows     (N_input,) bool the input rows of the scan file that are these points (absent
                                   when every row is one: no NaN, inf or no-return rows); exports
                                   spread per-point values back to the input rows with it

Files are `.npz` archives readable by `numpy.load`: points and intensity stored, the rest deflated
(see STORED_ARRAYS). They are written to a temporary name and renamed, so a reader never sees a
partial file.
"""

from __future__ import annotations

import hashlib
import io
import os
import threading
import zipfile
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.viewer_payload import PAYLOAD_ARRAYS, frame_payload, payload_from_artifact


@dataclass(frozen=True)
class FrameArtifact:
    """The arrays of one frame (shapes in the module docstring)."""

    points: np.ndarray
    intensity: np.ndarray
    segment: np.ndarray
    ground: np.ndarray
    track: np.ndarray
    samples: np.ndarray
    sample_segment: np.ndarray
    input_rows: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.points)
        assert self.points.shape == (n, 3) and self.points.dtype == np.float32, self.points.shape
        assert self.intensity.shape == (n,) and self.intensity.dtype == np.float32
        assert self.segment.shape == (n,) and self.segment.dtype == np.int32
        assert self.ground.shape == (n,) and self.ground.dtype == np.bool_
        assert self.track.shape == (n,) and self.track.dtype == np.int64
        assert self.samples.ndim == 4 and self.samples.dtype == np.uint8, self.samples.shape
        assert self.sample_segment.shape == (len(self.samples),) and self.sample_segment.dtype == np.int32
        rows = self.input_rows
        assert rows is None or (rows.ndim == 1 and rows.dtype == np.bool_ and int(rows.sum()) == n)


# Coordinates and intensities are float noise to deflate (it saves ~10 % and costs most of a
# payload's read time), so they are stored; segment/track/ground ids and samples are long runs
# that deflate 30-100x.
STORED_ARRAYS = frozenset({"points", "intensity"})


class ArtifactMissing(FileNotFoundError):
    """A row points at an artifact file that is not there."""


class ArtifactStore:
    """Reads and writes frame artifacts under `root`; keeps recent viewer payloads in an LRU of
    `payload_cache_bytes` (keyed by path and file mtime, so a rewritten frame is never stale)."""

    def __init__(self, root: str | Path, payload_cache_bytes: int = 0) -> None:
        self.root = Path(root)
        self._real_root = self.root.resolve()
        self._cache: OrderedDict[tuple[str, int], memoryview] = OrderedDict()
        self._cache_bytes = 0
        self._cache_limit = payload_cache_bytes
        self._lock = threading.Lock()

    def frame_relpath(self, sequence_id: int, index: int, revision: str | None = None) -> str:
        """`seq_<id>/<index>.npz`; a frame rewritten by a track split or merge gets a new file,
        `<index>.<revision>.npz`, and the old one stays for undo (app/services/repair.py)."""
        suffix = "" if revision is None else f".{revision}"
        return f"seq_{sequence_id:06d}/{index:06d}{suffix}.npz"

    def path(self, relpath: str) -> Path:
        """The file of `relpath`; ArtifactMissing when its real path leaves the artifact folder
        (a link planted there is never followed out of it)."""
        path = self.root / relpath
        real = path.resolve()
        if not real.is_relative_to(self._real_root):
            raise ArtifactMissing(f"artifact {relpath} resolves outside the artifact folder")
        return path

    def write_frame(self, sequence_id: int, index: int, frame: FrameArtifact, revision: str | None = None) -> str:
        """Write one frame atomically; returns its relative path."""
        rel = self.frame_relpath(sequence_id, index, revision)
        dest = self.path(rel)
        dest.parent.mkdir(parents=True, exist_ok=True)
        tmp = dest.with_name(f".{dest.name}.{os.getpid()}.tmp")
        with zipfile.ZipFile(tmp, "w", allowZip64=True) as zf:
            for name, arr in frame.__dict__.items():
                if arr is None:
                    continue
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.ascontiguousarray(arr), allow_pickle=False)
                stored = name in STORED_ARRAYS
                zf.writestr(
                    zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0)),
                    buf.getbuffer(),
                    compress_type=zipfile.ZIP_STORED if stored else zipfile.ZIP_DEFLATED,
                    compresslevel=None if stored else 1,  # long runs: level 1 packs them as well
                )
        os.replace(tmp, dest)
        return rel

    def read_frame(self, relpath: str) -> FrameArtifact:
        with np.load(self.path(relpath)) as z:
            return FrameArtifact(**{k: z[k] for k in FrameArtifact.__dataclass_fields__ if k in z.files})

    def read_arrays(self, relpath: str, names: tuple[str, ...]) -> dict[str, np.ndarray]:
        """Only the named arrays of a frame that it holds (npz members are decompressed lazily)."""
        try:
            with np.load(self.path(relpath)) as z:
                return {k: z[k] for k in names if k in z.files}
        except FileNotFoundError:
            raise ArtifactMissing(f"artifact {relpath} is missing") from None

    def payload(self, relpath: str) -> memoryview:
        """The viewer payload of a frame (app/viewer_payload.py), from the LRU when it is there."""
        path = self.path(relpath)
        try:
            key = (relpath, path.stat().st_mtime_ns)
        except FileNotFoundError:
            raise ArtifactMissing(f"artifact {relpath} is missing") from None
        with self._lock:
            body = self._cache.get(key)
            if body is not None:
                self._cache.move_to_end(key)
                return body
        try:
            body = payload_from_artifact(path)
        except FileNotFoundError:
            raise ArtifactMissing(f"artifact {relpath} is missing") from None
        if body is None:  # a layout the fast path does not expect: decode and re-encode
            body = memoryview(frame_payload(self.read_arrays(relpath, PAYLOAD_ARRAYS)))
        if len(body) <= self._cache_limit:
            with self._lock:
                if key not in self._cache:
                    self._cache[key] = body
                    self._cache_bytes += len(body)
                while self._cache_bytes > self._cache_limit:
                    _, old = self._cache.popitem(last=False)
                    self._cache_bytes -= len(old)
        return body

    def remove_sequence(self, sequence_id: int) -> None:
        folder = self.root / f"seq_{sequence_id:06d}"
        if folder.is_dir():
            for f in folder.iterdir():
                f.unlink(missing_ok=True)


def frame_etag(artifact: str) -> str:
    """The strong ETag (quoted) of a frame whose artifact file is `artifact`. A frame's version is
    its artifact file: a split, a merge or their undo points the frame at another file
    (`<index>.<revision>.npz`) and nothing else changes a frame's points, so the file's name is
    the frame's ETag (a track's version is its `version` column)."""
    return '"' + hashlib.sha1(artifact.encode()).hexdigest()[:16] + '"'
