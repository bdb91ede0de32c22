"""Track split, merge and undo over the REST API (fake pipeline: object points scattered around
the origin, so a half-space x >= 0 cuts about half of every segment of a track)."""

from __future__ import annotations

import io
import tarfile

import numpy as np
import pytest
from sqlalchemy import select

from app import crud
from app.artifacts import ArtifactStore
from app.models import Frame, Label, PairConstraint, Segment, Track
from tests.app.fakes import fake_pipeline

HALF = {"kind": "halfspace", "normal": [1.0, 0.0, 0.0], "offset": 0.0}


@pytest.fixture(autouse=True)
def fake_backend():
    with fake_pipeline():
        yield


def _post(client, caller, track_id, action, body, status=200):
    r = client.post(f"/api/v1/tracks/{track_id}/{action}", json=body, headers=caller.headers)
    assert r.status_code == status, r.text
    return r.json()


def _points_of(factory, settings, track_id):
    """{frame index: (N,) bool} points of the track per frame, read from the artifacts."""
    out = {}
    with factory.db.read() as s:
        frames = s.execute(select(Frame.index, Frame.artifact).order_by(Frame.index)).all()
    for index, rel in frames:
        art = np.load(settings.data_dir / "artifacts" / rel)
        out[index] = (art["track"] == track_id, art["points"])
    return out


def _snapshot(factory, sequence_id):
    """Every row a split or merge may change, as plain values."""
    with factory.db.read() as s:
        def rows(model, *where, skip=("updated_at", "created_at")):
            return sorted(
                tuple((c.name, getattr(r, c.name)) for c in model.__table__.columns if c.name not in skip)
                for r in s.scalars(select(model).where(*where)).all()
            )
        tracks = [
            tuple(getattr(t, f) for f in ("id", "key", "status", "label", "first_frame", "last_frame", "keep_start", "keep_end",
                                          "length", "n_samples", "n_points", "mean_range"))
            for t in s.scalars(select(Track).where(Track.sequence_id == sequence_id).order_by(Track.id)).all()
        ]
        return {
            "tracks": tracks,
            "segments": rows(Segment, Segment.sequence_id == sequence_id),
            "constraints": rows(PairConstraint, PairConstraint.sequence_id == sequence_id),
            # labels are materialised from the track's decision again: equal rows, new ids
            "labels": rows(Label, Label.sequence_id == sequence_id, skip=("id", "created_at")),
            "frames": rows(Frame, Frame.sequence_id == sequence_id),
        }


def test_repair_split_moves_the_region_to_a_new_track(client, factory, settings):
    seq = factory.ingested_sequence(n_frames=4, n_objects=2)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    before = _points_of(factory, settings, tid)
    expect = {f: m & (p[:, 0] >= 0) for f, (m, p) in before.items()}
    out = _post(client, op, tid, "split", {"version": 1, "region": HALF})
    new = out["new_track"]["id"]
    assert out["track"]["version"] == 2 and out["new_track"]["version"] == 1 and out["new_track"]["status"] == "pending"
    assert out["moved_points"] == sum(int(m.sum()) for m in expect.values())
    after_new = _points_of(factory, settings, new)
    after_old = _points_of(factory, settings, tid)
    for f in before:
        assert np.array_equal(after_new[f][0], expect[f])
        assert np.array_equal(after_old[f][0], before[f][0] & ~expect[f])
    detail = client.get(f"/api/v1/tracks/{new}", headers=op.headers).json()
    assert detail["n_points"] == out["moved_points"] and len(detail["segments"]) == 4
    assert all(s["sample_url"] for s in detail["segments"])  # > 3 points each: valid, re-rendered


def test_repair_split_current_frame_only(client, factory, settings):
    seq = factory.ingested_sequence(n_frames=4, n_objects=1)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    out = _post(client, op, tid, "split", {"version": 1, "region": HALF, "frame_index": 2})
    new = client.get(f"/api/v1/tracks/{out['new_track']['id']}", headers=op.headers).json()
    assert [s["frame_index"] for s in new["segments"]] == [2]
    assert (new["first_frame"], new["last_frame"], new["keep_start"], new["keep_end"]) == (2, 2, 2, 2)


def test_repair_split_stale_version_409(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    _post(client, op, tid, "accept", {"version": 1})
    _post(client, op, tid, "split", {"version": 1, "region": HALF}, status=409)


def test_repair_split_unknown_track_404(client, factory):
    factory.ingested_sequence(n_frames=3, n_objects=1)
    _post(client, factory.user(), 999_999, "split", {"version": 1, "region": HALF}, status=404)


@pytest.mark.parametrize("offset, words", [(1e6, "no point"), (-1e6, "every point")])
def test_repair_split_region_selecting_nothing_or_everything_409(client, factory, offset, words):
    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    r = client.post(f"/api/v1/tracks/{tid}/split", json={"version": 1, "region": {**HALF, "offset": offset}},
                    headers=op.headers)
    assert r.status_code == 409 and words in r.json()["detail"]  # well-formed, ruled out by the track's points
    assert factory.track(tid).version == 1


def test_repair_split_bad_region_422(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    bad = {"kind": "box", "center": [0, 0, 0], "size": [0, 1, 1]}
    _post(client, op, tid, "split", {"version": 1, "region": bad}, status=422)


def test_repair_split_box_and_height_regions(client, factory, settings):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user()
    a, b = factory.track_ids(seq)
    box = {"kind": "box", "center": [0, 0, 0], "size": [100, 100, 10], "wxyz": [0.92388, 0, 0, 0.38268]}
    before = _points_of(factory, settings, a)
    out = _post(client, op, a, "split", {"version": 1, "region": box})
    # a 10 m tall box (z within +-5) rotated about z: only z decides for points this close
    assert out["moved_points"] == sum(int((m & (np.abs(p[:, 2]) <= 5)).sum()) for m, p in before.values())
    before_b = _points_of(factory, settings, b)
    out = _post(client, op, b, "split", {"version": 1, "region": {"kind": "height", "min_height": 22.0}})
    assert out["moved_points"] == sum(int((m & (p[:, 2] >= 2.0)).sum()) for m, p in before_b.values())


def test_repair_split_exports_give_each_part_its_class_and_instance(client, factory, settings):
    from pipeline.classes import SEMANTICKITTI_WRITE_ID

    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    before = _points_of(factory, settings, tid)
    out = _post(client, op, tid, "split", {"version": 1, "region": HALF})
    new = out["new_track"]
    _post(client, op, tid, "label", {"version": 2, "label": "bush"})
    _post(client, op, new["id"], "label", {"version": 1, "label": "person"})
    tar = tarfile.open(fileobj=io.BytesIO(client.get(f"/api/v1/exports/semantickitti/{seq}", headers=op.headers).content))
    for f, (mask, pts) in before.items():
        label = np.frombuffer(tar.extractfile(f"sequences/seq/labels/{f:06d}.label").read(), np.uint32)
        cut = mask & (pts[:, 0] >= 0)
        assert set(label[cut].tolist()) == {SEMANTICKITTI_WRITE_ID["person"] | (new["key"] << 16)}
        assert set(label[mask & ~cut].tolist()) == {SEMANTICKITTI_WRITE_ID["bush"] | (1 << 16)}
    rows = client.get("/api/v1/exports/labels", params={"sequence_id": seq}, headers=op.headers).text.splitlines()
    assert len(rows) == 6  # three frames, each with a sample of either part
    z = np.load(io.BytesIO(client.get("/api/v1/exports/labels", params={"sequence_id": seq, "format": "npz"},
                                      headers=op.headers).content))
    # re-rendered samples (fake pipeline: 100 + segment id): segment 0 kept, segment 2 is new
    assert sorted(set(z["samples"][:, 0, 0, 0].tolist())) == [100, 102]
    constraints = client.get("/api/v1/exports/constraints", params={"sequence_id": seq}, headers=op.headers)
    assert {int(r.split('"track_id": ')[1].split(",")[0]) for r in constraints.text.splitlines()} == {tid, new["id"]}


def test_repair_split_training_set_sees_both_parts(client, factory, settings):
    from app.crud.model_versions import load_training_set

    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    new = _post(client, op, tid, "split", {"version": 1, "region": HALF})["new_track"]
    _post(client, op, tid, "label", {"version": 2, "label": "bush"})
    _post(client, op, new["id"], "label", {"version": 1, "label": "person"})
    with factory.db.read() as s:
        ts = load_training_set(s, ArtifactStore(settings.data_dir / "artifacts"), [seq])
    from pipeline.classes import SAMPLE_CLASSES

    labels = sorted(ts.data.labels.tolist())
    assert labels == sorted([SAMPLE_CLASSES.index("bush")] * 3 + [SAMPLE_CLASSES.index("person")] * 3)
    assert len(ts.data.pairs) == 4  # two links per part over three frames


def test_repair_undo_split_restores_rows_and_files_exactly(client, factory, settings):
    seq = factory.ingested_sequence(n_frames=4, n_objects=2)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    _post(client, op, tid, "label", {"version": 1, "label": "car"})
    snap = _snapshot(factory, seq)
    arrays = _points_of(factory, settings, tid)
    _post(client, op, tid, "split", {"version": 2, "region": HALF})
    assert _snapshot(factory, seq) != snap
    out = _post(client, op, tid, "undo", {"version": 3})
    assert out["version"] == 4 and out["label"] == "car"
    assert _snapshot(factory, seq) == snap
    for f, (m, p) in _points_of(factory, settings, tid).items():
        assert np.array_equal(m, arrays[f][0]) and np.array_equal(p, arrays[f][1])


def test_repair_undo_split_refused_when_the_new_track_changed(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    new = _post(client, op, tid, "split", {"version": 1, "region": HALF})["new_track"]
    _post(client, op, new["id"], "accept", {"version": 1})
    r = client.post(f"/api/v1/tracks/{tid}/undo", json={"version": 2}, headers=op.headers)
    assert r.status_code == 409 and "changed since" in r.json()["detail"]
    _post(client, op, new["id"], "undo", {"version": 2})  # its action undone: the split can go
    _post(client, op, tid, "undo", {"version": 2})
    _post(client, op, new["id"], "accept", {"version": 3}, status=404)


def test_repair_undo_with_nothing_to_undo_says_so(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    op = factory.user()
    r = client.post(f"/api/v1/tracks/{factory.track_ids(seq)[0]}/undo", json={"version": 1}, headers=op.headers)
    assert r.status_code == 409 and r.json()["detail"].startswith("nothing to undo")


def test_repair_merge_joins_two_tracks(client, factory, settings):
    seq = factory.ingested_sequence(n_frames=4, n_objects=2)
    op = factory.user()
    a, b = factory.track_ids(seq)
    pts_a, pts_b = _points_of(factory, settings, a), _points_of(factory, settings, b)
    out = _post(client, op, a, "merge", {"version": 1, "other_track_id": b, "other_version": 1})
    assert out["version"] == 2 and out["n_points"] == sum(int(m.sum()) for m, _ in [*pts_a.values(), *pts_b.values()])
    other = factory.track(b)
    assert other.status == "merged" and other.version == 2 and other.n_points == 0
    joined = _points_of(factory, settings, a)
    for f in joined:
        assert np.array_equal(joined[f][0], pts_a[f][0] | pts_b[f][0])
    with factory.db.read() as s:
        pairs = s.scalars(select(PairConstraint).where(PairConstraint.track_id == a)).all()
        assert len(pairs) == 6  # 4 + 3 segments (object 1 starts at frame 1) chained in frame order
        assert crud.rebuild_review_state(s, factory.track(a)) == crud.review_state(factory.track(a))
    _post(client, op, b, "accept", {"version": 2}, status=409)  # a merged track takes no action


def test_repair_merge_stale_other_version_409(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user()
    a, b = factory.track_ids(seq)
    _post(client, op, b, "accept", {"version": 1})
    _post(client, op, a, "merge", {"version": 1, "other_track_id": b, "other_version": 1}, status=409)
    _post(client, op, a, "merge", {"version": 1, "other_track_id": a, "other_version": 1}, status=409)
    _post(client, op, a, "merge", {"version": 1, "other_track_id": 999_999, "other_version": 1}, status=404)


@pytest.mark.parametrize("undo_on", ["target", "merged"])
def test_repair_undo_merge_restores_both_tracks(client, factory, undo_on):
    seq = factory.ingested_sequence(n_frames=4, n_objects=2)
    op = factory.user()
    a, b = factory.track_ids(seq)
    _post(client, op, b, "label", {"version": 1, "label": "car"})
    snap = _snapshot(factory, seq)
    _post(client, op, a, "merge", {"version": 1, "other_track_id": b, "other_version": 2})
    _post(client, op, a if undo_on == "target" else b, "undo", {"version": 2 if undo_on == "target" else 3})
    assert _snapshot(factory, seq) == snap
    assert factory.track(a).version == 3 and factory.track(b).version == 4


def test_repair_replaying_split_events_reproduces_the_split(client, factory, settings):
    """The split event records its region: posting it again on an identically ingested sequence
    gives the same per-point assignment."""
    seq_a = factory.ingested_sequence(n_frames=3, n_objects=1, name="a")
    seq_b = factory.ingested_sequence(n_frames=3, n_objects=1, name="b")
    op = factory.user()
    ta, tb = factory.track_ids(seq_a)[0], factory.track_ids(seq_b)[0]
    _post(client, op, ta, "split", {"version": 1, "region": HALF, "frame_index": 1})
    events = client.get(f"/api/v1/tracks/{ta}/events", headers=op.headers).json()
    split = [e for e in events if e["action"] == "split"][0]
    replay = _post(client, op, tb, "split", {"version": 1, "region": split["detail"]["region"],
                                              "frame_index": split["detail"]["frame_index"]})
    new_a = split["detail"]["new_track"]
    with factory.db.read() as s:
        arts = {sid: s.execute(select(Frame.artifact).where(Frame.sequence_id == sid).order_by(Frame.index)).scalars().all()
                for sid in (seq_a, seq_b)}
    for rel_a, rel_b in zip(arts[seq_a], arts[seq_b], strict=True):
        za, zb = np.load(settings.data_dir / "artifacts" / rel_a), np.load(settings.data_dir / "artifacts" / rel_b)
        assert np.array_equal(za["track"] == new_a, zb["track"] == replay["new_track"]["id"])
        assert np.array_equal(za["segment"], zb["segment"])


def test_repair_split_by_predicted_class_moves_whole_segments(client, factory, db, tmp_path):
    """An untrained model still answers deterministically: the segments it calls `car` go."""
    import torch

    from app.crud import model_versions
    from pipeline.classes import SAMPLE_CLASSES
    from pipeline.config import ModelConfig, SampleConfig
    from pipeline.model import get_model, load_checkpoint, predict, save_checkpoint
    from tests.app.fakes import SAMPLE_SHAPE

    torch.manual_seed(0)
    mc = ModelConfig(width=4, max_width=8, depth=2, dropout=0.0)
    sc = SampleConfig(size=SAMPLE_SHAPE[1], foreground_channel=True)
    path = save_checkpoint(tmp_path / "m.pt", get_model(mc, sc), mc, sc)
    with db.write() as s:
        model_id = model_versions.register_model_version(s, name="m", kind="train", path=path).id
        s.commit()
    seq = factory.ingested_sequence(n_frames=5, n_objects=1)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    # what the model says of each of the track's samples (fake sample value = frame * 7)
    model, meta = load_checkpoint(path, "cpu")
    samples = np.stack([np.full(SAMPLE_SHAPE, f * 7, np.uint8) for f in range(5)])
    classes = [meta.classes[int(p.argmax())] for p in predict(model, samples)]
    cls = classes[2]
    region = {"kind": "predicted", "model_id": model_id, "class_name": cls}
    out = _post(client, op, tid, "split", {"version": 1, "region": region, "frame_index": 2})
    new = client.get(f"/api/v1/tracks/{out['new_track']['id']}", headers=op.headers).json()
    assert [s["frame_index"] for s in new["segments"]] == [2] and out["moved_points"] == 20
    other = next((c for c in SAMPLE_CLASSES if c != cls), None)
    if other not in classes:  # a class the model gives no segment: nothing is selected
        _post(client, op, tid, "split", {"version": 2, "region": {**region, "class_name": other}}, status=409)
    _post(client, op, tid, "split", {"version": 2, "region": {**region, "class_name": "spaceship"}}, status=409)


def test_repair_split_and_merge_by_an_operator_without_the_lease_409(client, factory):
    """While one operator holds a track's lease, another can neither split it nor merge it (either side)."""
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    holder, other = factory.user("operator", "ann"), factory.user("operator", "bob")
    leased = client.post("/api/v1/review/next", headers=holder.headers).json()
    free = next(t for t in factory.track_ids(seq) if t != leased["id"])
    r = client.post(f"/api/v1/tracks/{leased['id']}/split", json={"version": leased["version"], "region": HALF},
                    headers=other.headers)
    assert r.status_code == 409 and "ann" in r.json()["detail"]
    r = client.post(f"/api/v1/tracks/{free}/merge", headers=other.headers,
                    json={"version": 1, "other_track_id": leased["id"], "other_version": leased["version"]})
    assert r.status_code == 409 and "ann" in r.json()["detail"]
    assert factory.track(leased["id"]).version == leased["version"] and factory.track(free).version == 1
    _post(client, holder, leased["id"], "split", {"version": leased["version"], "region": HALF})  # the holder may


def test_repair_split_after_undo_gets_a_fresh_id_and_key(client, factory):
    """split -> undo -> split: the second part is a new track (new id, new key, so a new export
    instance id); an edit sent with the undone track's id and version gets 404, never lands on it."""
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user()
    tid = factory.track_ids(seq)[-1]  # the highest id and key: SQLite would hand both out again
    first = _post(client, op, tid, "split", {"version": 1, "region": HALF})["new_track"]
    _post(client, op, tid, "undo", {"version": 2})
    second = _post(client, op, tid, "split", {"version": 3, "region": HALF})["new_track"]
    assert second["id"] > first["id"] and second["key"] > first["key"]
    _post(client, op, first["id"], "accept", {"version": first["version"]}, status=404)
    assert factory.track(second["id"]).version == 1


def test_repair_merged_track_length_counts_frames_after_truncate(client, factory):
    """Two tracks seen in the same frames merged: two segments per frame, but length is frames."""
    seq = factory.ingested_sequence(n_frames=4, n_objects=2)  # object 0 in frames 0-3, object 1 in 1-3
    op = factory.user()
    a, b = factory.track_ids(seq)
    out = _post(client, op, a, "merge", {"version": 1, "other_track_id": b, "other_version": 1})
    assert out["length"] == 4
    out = _post(client, op, a, "truncate", {"version": 2, "start": 1, "end": 3})
    assert out["length"] == 3 and out["n_samples"] == 6


def test_repair_rows_written_back_with_only_nulls_keep_their_column_types(factory, db):
    """Undoing a split restores the split segment rows; when every restored `link_score` is NULL
    (the split pieces were track starts), PostgreSQL typed the CASE over bare NULLs as text and
    the undo answered 500."""
    from app.services.repair_common import SEGMENT_FIELDS, update_segments

    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    with db.write() as s:
        seg = s.scalars(select(Segment).where(Segment.sequence_id == seq).order_by(Segment.id)).first()
        row = {"id": seg.id, **{f: getattr(seg, f) for f in SEGMENT_FIELDS}, "link_score": None, "sample_index": None}
        update_segments(s, [row])
        s.commit()
    with db.read() as s:
        back = s.get(Segment, row["id"])
        assert back.link_score is None and back.sample_index is None and back.cx == pytest.approx(row["cx"])
