"""Review progress, and the labels and constraints that training reads."""

from __future__ import annotations

from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.crud.bulk import operation_count
from app.models import BulkAction, Label, PairConstraint, Segment, Stitch, Track


def _count_by(session: Session, column: Any, where: list[Any]) -> dict[str, int]:
    """Rows per value of `column` among those matching `where`."""
    return {k: int(v) for k, v in session.execute(select(column, func.count()).where(*where).group_by(column)).all()}


def progress_stats(session: Session, sequence_id: int | None) -> dict[str, Any]:
    """Tracks by status, reviewed tracks, samples labelled per class, constraint counts; accepted
    tracks and labelled samples by label source, bulk accepts and (per sequence) operations."""
    t_where = [] if sequence_id is None else [Track.sequence_id == sequence_id]
    by_status = _count_by(session, Track.status, t_where)
    by_source = _count_by(session, Track.label_source, [*t_where, Track.status == "accepted", Track.label_source.is_not(None)])
    l_where = [] if sequence_id is None else [Label.sequence_id == sequence_id]
    per_class = _count_by(session, Label.class_name, l_where)
    per_source = _count_by(session, Label.source, l_where)
    b_where = [] if sequence_id is None else [BulkAction.sequence_id == sequence_id]
    bulks = session.scalar(select(func.count()).select_from(BulkAction).where(*b_where)) or 0
    s_where = [Segment.valid.is_(True)] + ([] if sequence_id is None else [Segment.sequence_id == sequence_id])
    samples = session.scalar(select(func.count()).select_from(Segment).where(*s_where)) or 0
    c_where = [] if sequence_id is None else [PairConstraint.sequence_id == sequence_id]
    automatic = session.scalar(select(func.count()).select_from(PairConstraint).where(*c_where)) or 0
    verified = session.scalar(
        select(func.count()).select_from(verified_constraints_query(sequence_id).subquery())
    ) or 0
    return {
        "tracks": sum(by_status.values()),
        "tracks_by_status": by_status,
        "tracks_reviewed": sum(v for k, v in by_status.items() if k != "pending"),
        "samples": int(samples),
        "samples_labelled": sum(per_class.values()),
        "samples_labelled_per_class": per_class,
        "constraints_automatic": int(automatic),
        "constraints_verified": int(verified),
        "tracks_accepted_by_source": by_source,
        "samples_labelled_per_source": per_source,
        "bulk_actions": int(bulks),
        "operations": None if sequence_id is None else operation_count(session, sequence_id),
    }


def constraints_query(sequence_id: int | None, verified_only: bool) -> Any:
    """Constraint pairs inside the kept range of non-discarded tracks (accepted only when verified_only).

    Two kinds: track links (`must_link`, both segments in one track) and the fragment links of
    stitches (`fragment`: each segment in its own track's kept range, both tracks not discarded and
    the stitch not rejected; verified when the stitch is confirmed and both tracks are accepted).

    Columns: id, track_id, segment_a_id, segment_b_id, frame_a, frame_b, score, verified.
    """
    from sqlalchemy import and_, union_all
    from sqlalchemy.orm import aliased

    def pairs_with_segments(sa: Any, sb: Any, verified: Any) -> Any:
        """The pair rows joined to their two segments `sa`, `sb` (aliases of Segment)."""
        return (
            select(PairConstraint.id, PairConstraint.track_id, PairConstraint.segment_a_id,
                   PairConstraint.segment_b_id, sa.frame_index.label("frame_a"), sb.frame_index.label("frame_b"),
                   PairConstraint.score, verified.label("verified"))
            .join(sa, sa.id == PairConstraint.segment_a_id)
            .join(sb, sb.id == PairConstraint.segment_b_id)
        )

    sa, sb = aliased(Segment), aliased(Segment)
    links = (
        pairs_with_segments(sa, sb, Track.status == "accepted")
        .join(Track, Track.id == PairConstraint.track_id)
        .where(
            PairConstraint.kind == "must_link",
            Track.status != "discarded",
            sa.frame_index >= Track.keep_start,
            sb.frame_index <= Track.keep_end,
        )
    )
    fa, fb = aliased(Segment), aliased(Segment)
    ta, tb = aliased(Track), aliased(Track)
    frag_verified = and_(Stitch.status == "confirmed", ta.status == "accepted", tb.status == "accepted")
    fragments = (
        pairs_with_segments(fa, fb, frag_verified)
        .join(Stitch, Stitch.id == PairConstraint.stitch_id)
        .join(ta, ta.id == fa.track_id)
        .join(tb, tb.id == fb.track_id)
        .where(
            PairConstraint.kind == "fragment",
            Stitch.status != "rejected",
            ta.status != "discarded",
            tb.status != "discarded",
            fa.frame_index.between(ta.keep_start, ta.keep_end),
            fb.frame_index.between(tb.keep_start, tb.keep_end),
        )
    )
    if sequence_id is not None:
        links = links.where(PairConstraint.sequence_id == sequence_id)
        fragments = fragments.where(PairConstraint.sequence_id == sequence_id)
    if verified_only:
        links = links.where(Track.status == "accepted")
        fragments = fragments.where(frag_verified)
    both = union_all(links, fragments).subquery()
    return select(both).order_by(both.c.id)


def verified_constraints_query(sequence_id: int | None) -> Any:
    return constraints_query(sequence_id, verified_only=True)


def labels_query(sequence_id: int | None) -> Any:
    """Labelled samples: label id, segment id, track id, frame index, class name and index."""
    q = (
        select(
            Label.segment_id,
            Label.track_id,
            Segment.frame_index,
            Label.class_name,
            Label.class_index,
        )
        .join(Segment, Segment.id == Label.segment_id)
        .order_by(Label.segment_id)
    )
    if sequence_id is not None:
        q = q.where(Label.sequence_id == sequence_id)
    return q


def segment_classes(session: Session, sequence_id: int, source: str | None = None) -> dict[int, int]:
    """Class index per labelled segment of the sequence; only the labels from `source` when given
    ("review": an operator's, not a bulk accept's)."""
    q = select(Label.segment_id, Label.class_index).where(Label.sequence_id == sequence_id)
    if source is not None:
        q = q.where(Label.source == source)
    return {int(seg): int(cls) for seg, cls in session.execute(q).all()}


def track_label_rows(session: Session, sequence_id: int) -> list[Any]:
    """(track id, key, label, keep_start, keep_end) of accepted, labelled tracks."""
    return list(
        session.execute(
            select(Track.id, Track.key, Track.label, Track.keep_start, Track.keep_end).where(
                Track.sequence_id == sequence_id, Track.status == "accepted", Track.label.is_not(None)
            )
        ).all()
    )
