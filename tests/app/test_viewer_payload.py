"""The viewer payload built from an artifact's ZIP members equals the one built from its arrays."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest

from app.artifacts import ArtifactStore, FrameArtifact
from app.viewer_payload import PAYLOAD_ARRAYS, frame_payload, payload_from_artifact


def _frame(n: int, track_offset: int = 100) -> FrameArtifact:
    rng = np.random.default_rng(n)
    seg = np.sort(rng.integers(-1, max(n // 20, 1), n)).astype(np.int32)
    return FrameArtifact(
        points=rng.normal(size=(n, 3)).astype(np.float32),
        intensity=rng.random(n, dtype=np.float32),
        segment=seg,
        ground=seg < 0,
        track=np.where(seg >= 0, seg.astype(np.int64) + track_offset, 0),
        samples=np.zeros((2, 4, 8, 8), np.uint8),
        sample_segment=np.arange(2, dtype=np.int32),
    )


def _arrays(body) -> dict[str, np.ndarray]:
    zf = zipfile.ZipFile(io.BytesIO(body))
    assert zf.testzip() is None  # every CRC-32 matches
    assert all(i.compress_type == zipfile.ZIP_STORED for i in zf.infolist())
    with np.load(io.BytesIO(body)) as z:
        assert sorted(z.files) == sorted(PAYLOAD_ARRAYS)
        return {k: z[k] for k in PAYLOAD_ARRAYS}


def _same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    return all(a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]) for k in PAYLOAD_ARRAYS)


@pytest.mark.parametrize("n", [0, 1, 70_000])
def test_viewer_payload_from_artifact_equals_payload_from_arrays(tmp_path, n):
    store = ArtifactStore(tmp_path)
    fa = _frame(n)
    rel = store.write_frame(1, 0, fa)
    fast = _arrays(payload_from_artifact(store.path(rel)))
    assert _same(fast, _arrays(frame_payload(fa.__dict__)))
    assert fast["track"].dtype == np.int32 and np.array_equal(fast["track"], fa.track)


def test_viewer_payload_keeps_int64_track_ids_past_2_31(tmp_path):
    store = ArtifactStore(tmp_path)
    fa = _frame(500, track_offset=2**31)
    payload = _arrays(payload_from_artifact(store.path(store.write_frame(1, 0, fa))))
    assert payload["track"].dtype == np.int64 and np.array_equal(payload["track"], fa.track)


def test_viewer_payload_of_an_all_deflated_artifact(tmp_path):
    # an artifact written with every member compressed (np.savez_compressed) gives the same payload
    fa = _frame(3000)
    path = tmp_path / "old.npz"
    np.savez_compressed(path, **fa.__dict__)
    assert _same(_arrays(payload_from_artifact(path)), _arrays(frame_payload(fa.__dict__)))


def _write_npz(path, arrays, compression):
    with zipfile.ZipFile(path, "w", compression=compression) as zf:
        for k, v in arrays.items():
            if v is None:  # an optional array the frame does not have
                continue
            buf = io.BytesIO()
            np.lib.format.write_array(buf, v)
            zf.writestr(f"{k}.npy", buf.getvalue())


def test_viewer_payload_falls_back_on_an_unexpected_layout(tmp_path):
    fa = _frame(300)
    _write_npz(tmp_path / "bz2.npz", fa.__dict__, zipfile.ZIP_BZIP2)  # a compression it does not inflate
    _write_npz(tmp_path / "float.npz", {**fa.__dict__, "track": fa.track.astype(np.float64)}, zipfile.ZIP_STORED)
    assert payload_from_artifact(tmp_path / "bz2.npz") is None and payload_from_artifact(tmp_path / "float.npz") is None
    store = ArtifactStore(tmp_path)
    assert _same(_arrays(store.payload("bz2.npz")), _arrays(frame_payload(fa.__dict__)))
