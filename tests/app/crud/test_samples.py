"""The reads and writes the model jobs make of a sequence's samples, tracks, labels, review
events and anchor proposals (app/jobs/predict.py, assist.py, anchors.py)."""

from __future__ import annotations

from sqlalchemy import select

from app.crud.anchors import answered_proposals, proposal_candidates, store_proposals
from app.crud.frames import frame_artifacts, sample_segments
from app.crud.review import REVIEW_ACTIONS, review_events_after
from app.crud.statistics import segment_classes
from app.crud.tracks import set_predictions, track_ranges
from app.models import AnchorProposal, Label, Segment, Track


def _label(client, caller, track_id, version, label):
    r = client.post(f"/api/v1/tracks/{track_id}/label", json={"version": version, "label": label}, headers=caller.headers)
    assert r.status_code == 200, r.text


def test_samples_are_read_in_frame_then_sample_order_with_their_artifacts(db, factory):
    seq = factory.ingested_sequence(n_frames=4, n_objects=3)
    with db.read() as s:
        segs = sample_segments(s, seq)
        artifacts = frame_artifacts(s, seq)
        n = len(s.scalars(select(Segment.id).where(Segment.sequence_id == seq, Segment.sample_index.is_not(None))).all())
    assert len(segs) == n > 0 and len(artifacts) == 4
    assert [(r.frame_index, r.sample_index) for r in segs] == sorted((r.frame_index, r.sample_index) for r in segs)
    assert all(r.frame_id in artifacts for r in segs)


def test_tracks_set_predictions_writes_each_tracks_class_and_priority(db, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    ids = factory.track_ids(seq)
    with db.write() as s:
        set_predictions(s, [{"id": ids[0], "predicted_class": "car", "predicted_confidence": 0.75, "priority": 3.0},
                            {"id": ids[1], "predicted_class": None, "predicted_confidence": None, "priority": 1.0}])
    with db.read() as s:
        rows = {r.id: r for r in track_ranges(s, seq)}
        tracks = {t.id: t for t in s.scalars(select(Track).where(Track.sequence_id == seq))}
    assert set(rows) == set(ids)
    assert (tracks[ids[0]].predicted_class, tracks[ids[0]].predicted_confidence) == ("car", 0.75)
    assert tracks[ids[1]].predicted_class is None and tracks[ids[1]].priority == 1.0


def test_segment_classes_keep_only_the_labels_of_one_source(client, db, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user("operator")
    track = factory.track(factory.track_ids(seq)[0])
    _label(client, op, track.id, track.version, "car")
    with db.read() as s:
        labelled = set(s.scalars(select(Label.segment_id).where(Label.track_id == track.id)))
        assert labelled and set(segment_classes(s, seq)) == labelled
        assert set(segment_classes(s, seq, source="review")) == labelled
        assert segment_classes(s, seq, source="bulk") == {}


def test_review_events_after_counts_the_sequences_events_past_an_id(client, db, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    other = factory.ingested_sequence(n_frames=3, n_objects=2, name="other")
    op = factory.user("operator")
    for t in (factory.track(factory.track_ids(seq)[0]), factory.track(factory.track_ids(other)[0])):
        _label(client, op, t.id, t.version, "car")
    with db.read() as s:
        n, newest = review_events_after(s, seq, REVIEW_ACTIONS, 0)
        assert n == 1 and newest > 0
        assert review_events_after(s, seq, REVIEW_ACTIONS, newest) == (0, 0)
        assert review_events_after(s, seq, ("discard",), 0) == (0, 0)


def test_anchor_proposals_store_replaces_only_unanswered_ones(db, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    with db.read() as s:
        rows = proposal_candidates(s, seq)
    assert rows and all(r.track_id is not None for r in rows)

    def proposal(r, status="proposed"):
        return {"sequence_id": seq, "track_id": int(r.track_id), "segment_id": int(r.id), "score": 0.5,
                "status": status, "level": "sample"}

    with db.write() as s:
        assert store_proposals(s, seq, [proposal(rows[0], "confirmed"), proposal(rows[1])], replace=False) == 0
        assert store_proposals(s, seq, [proposal(rows[2])], replace=True) == 1
    with db.read() as s:
        statuses = sorted(s.scalars(select(AnchorProposal.status).where(AnchorProposal.sequence_id == seq)))
        assert statuses == ["confirmed", "proposed"]
        assert answered_proposals(s, seq, with_unanswered=False) == [(int(rows[0].id), int(rows[0].track_id), "sample")]
        assert len(answered_proposals(s, seq, with_unanswered=True)) == 2
