"""Database operations used by routes, jobs and the CLI. Routes stay thin and call these.

Write operations take a session from `Database.write` (BEGIN IMMEDIATE on SQLite) and commit
themselves; on PostgreSQL they lock the rows they change (`FOR UPDATE`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path, PurePath
from typing import Any

from sqlalchemy import (
    DateTime,
    Engine,
    Integer,
    String,
    bindparam,
    delete,
    func,
    insert,
    literal,
    or_,
    select,
    text,
    update,
)
from sqlalchemy.orm import Session

from app import leases
from app.core.errors import Conflict, Forbidden, Invalid, NotApplicable, NotFound
from app.core.security import hash_token, new_token, token_display_prefix
from app.models import (
    ROLES,
    AnchorProposal,
    AnnotationEvent,
    ApiToken,
    Dataset,
    Frame,
    Job,
    Label,
    PairConstraint,
    Segment,
    Sequence,
    Stitch,
    Track,
    User,
    utcnow,
)

# ----------------------------------------------------------------------------- users and tokens


@dataclass(frozen=True)
class AuthUser:
    """The caller, detached from any session."""

    id: int
    name: str
    role: str

    @property
    def is_admin(self) -> bool:
        return self.role == "admin"


def create_user(
    session: Session, name: str, role: str, created_by_id: int | None = None, expires_days: float = 90.0
) -> tuple[User, str]:
    """Create a user and a first token valid for `expires_days`; returns the user and the token
    (shown once). Commits."""
    if role not in ROLES:
        raise Invalid(f"unknown role {role!r}; valid: {', '.join(ROLES)}")
    if session.scalar(select(User.id).where(User.name == name)) is not None:
        raise Conflict(f"user {name!r} exists")
    user = User(name=name, role=role, created_by_id=created_by_id, active=True)
    session.add(user)
    session.flush()
    token = _add_token(session, user.id, created_by_id, expires_days)
    session.commit()
    return user, token


def create_token(session: Session, user_id: int, created_by_id: int | None = None, expires_days: float = 90.0) -> str:
    """A new token for an existing user, valid for `expires_days`, issued by `created_by_id`
    (None = the CLI). Commits."""
    if session.get(User, user_id) is None:
        raise NotFound(f"user {user_id} not found")
    token = _add_token(session, user_id, created_by_id, expires_days)
    session.commit()
    return token


def _add_token(session: Session, user_id: int, created_by_id: int | None, expires_days: float) -> str:
    if not 0 < expires_days <= 36500:
        raise Invalid(f"expires_days must be in (0, 36500], got {expires_days:g}")
    token = new_token()
    now = utcnow()
    session.add(ApiToken(user_id=user_id, token_hash=hash_token(token), prefix=token_display_prefix(token),
                         created_by_id=created_by_id, created_at=now, expires_at=now + timedelta(days=expires_days)))
    return token


def user_for_token(session: Session, token: str) -> AuthUser | None:
    """The active user owning an unrevoked, unexpired `token`, or None."""
    now = utcnow()
    row = session.execute(
        select(User.id, User.name, User.role)
        .join(ApiToken, ApiToken.user_id == User.id)
        .where(
            ApiToken.token_hash == hash_token(token),
            ApiToken.revoked_at.is_(None),
            or_(ApiToken.expires_at.is_(None), ApiToken.expires_at > now),
            User.active.is_(True),
        )
    ).first()
    return None if row is None else AuthUser(id=row.id, name=row.name, role=row.role)


def get_user_by_name(session: Session, name: str) -> User:
    user = session.scalar(select(User).where(User.name == name))
    if user is None:
        raise NotFound(f"user {name!r} not found")
    return user


def revoke_tokens(session: Session, *, user_id: int | None = None, prefix: str | None = None) -> int:
    """Revoke every live token of a user, or those whose display prefix starts with `prefix`
    (at least 6 characters, so that one typo cannot revoke everyone's). Returns how many; Commits."""
    where: list[Any] = [ApiToken.revoked_at.is_(None)]
    if user_id is not None:
        where.append(ApiToken.user_id == user_id)
    if prefix is not None:
        if len(prefix) < 6:
            raise Invalid(f"token prefix {prefix!r} is too short: give at least 6 characters (e.g. tl_AbC)")
        where.append(ApiToken.prefix.startswith(prefix[: len(token_display_prefix(prefix))], autoescape=True))
    if user_id is None and prefix is None:
        raise Invalid("name a user or a token prefix")
    n = session.execute(update(ApiToken).where(*where).values(revoked_at=utcnow())).rowcount
    if prefix is not None and n == 0:
        raise NotFound(f"no live token starts with {prefix!r}")
    session.commit()
    return int(n)


def set_user_active(session: Session, user_id: int, active: bool) -> User:
    """Disable (refused from the next request on; tokens kept) or re-enable a user. Commits."""
    user = session.get(User, user_id)
    if user is None:
        raise NotFound(f"user {user_id} not found")
    user.active = active
    session.commit()
    return user


def list_tokens(session: Session, user_id: int) -> list[ApiToken]:
    if session.get(User, user_id) is None:
        raise NotFound(f"user {user_id} not found")
    return list(session.scalars(select(ApiToken).where(ApiToken.user_id == user_id).order_by(ApiToken.id)).all())


# ----------------------------------------------------------------------------- datasets


def resolve_registration_path(raw: str, roots: list[Path]) -> Path:
    """The real path of `raw` if it lies under one of `roots`.

    `..` anywhere, or a (symlink-resolved) path outside every root -> Forbidden (403);
    a path under a root that does not exist -> NotFound. Relative paths are tried against each root.
    """
    if "\x00" in raw:
        raise Invalid("path contains a NUL byte")
    pure = PurePath(raw)
    if ".." in pure.parts:
        raise Forbidden("paths with '..' are refused")
    real_roots = [r.resolve() for r in roots]
    candidates = [Path(pure)] if pure.is_absolute() else [r / pure for r in real_roots]
    inside = False
    for cand in candidates:
        try:
            real = cand.resolve()
        except (OSError, RuntimeError, ValueError) as exc:
            raise Invalid(f"cannot resolve path: {exc}") from exc
        if any(real == r or real.is_relative_to(r) for r in real_roots):
            inside = True
            if real.exists():
                return real
    if not inside:
        raise Forbidden("path is outside the configured data roots")
    raise NotFound(f"no such file or folder under the data roots: {raw}")


def check_tree_inside_roots(path: Path, roots: list[Path]) -> None:
    """Forbidden (403) naming the first file or folder under `path` (or `path` itself) whose real
    path (symlinks resolved) lies outside every root: a link inside a root must not smuggle in a
    file from elsewhere. Checked at registration and again when ingest opens the sequence."""
    real_roots = [r.resolve() for r in roots]

    def inside(p: Path) -> bool:
        real = p.resolve()
        return any(real == r or real.is_relative_to(r) for r in real_roots)

    if not inside(path):
        raise Forbidden(f"{path.name} resolves outside the configured data roots")
    if not path.is_dir():
        return
    for folder, dirs, files in os.walk(path, followlinks=False):
        for name in (*dirs, *files):
            entry = Path(folder) / name
            if entry.is_symlink() and not inside(entry):
                raise Forbidden(
                    f"{entry.relative_to(path)} is a link to outside the configured data roots; refused"
                )


def registered_sequence_id(session: Session, path: Path) -> int | None:
    """The id of a sequence already registered at `path` (resolved), if any."""
    return session.scalar(select(Sequence.id).where(Sequence.path == str(path)).order_by(Sequence.id).limit(1))


def create_dataset(
    session: Session,
    path: Path,
    name: str | None,
    fmt: str,
    config: dict[str, Any] | None,
    user_id: int,
) -> tuple[Dataset, Sequence]:
    """Register one sequence path (already resolved and checked). Flushes, does not commit."""
    ds = Dataset(name=name or path.name, path=str(path), created_by_id=user_id)
    session.add(ds)
    session.flush()
    seq = Sequence(dataset_id=ds.id, name=name or path.name, path=str(path), format=fmt, config=config)
    session.add(seq)
    session.flush()
    return ds, seq


def sequence_stats(session: Session, seq: Sequence) -> dict[str, Any]:
    by_status = dict(
        session.execute(
            select(Track.status, func.count()).where(Track.sequence_id == seq.id).group_by(Track.status)
        ).all()
    )
    frames, segments, samples = session.execute(
        select(func.count(), func.coalesce(func.sum(Frame.n_segments), 0), func.coalesce(func.sum(Frame.n_samples), 0))
        .where(Frame.sequence_id == seq.id)
    ).one()
    constraints = session.scalar(select(func.count()).where(PairConstraint.sequence_id == seq.id)) or 0
    return {
        "frames": int(frames),
        "segments": int(segments),
        "samples": int(samples),
        "tracks": int(sum(by_status.values())),
        "tracks_by_status": {k: int(v) for k, v in by_status.items()},
        "constraints": int(constraints),
    }


# ----------------------------------------------------------------------------- jobs


def create_job(
    session: Session, job_type: str, params: dict[str, Any], user_id: int | None, priority: int = 0
) -> Job:
    """Queue a job (params already validated by its job type, the caller authorised by
    app.jobs.policy). Flushes, does not commit."""
    job = Job(type=job_type, params=params, status="queued", created_by_id=user_id, message="queued", priority=priority)
    session.add(job)
    session.flush()
    return job


def cancel_job(session: Session, job_id: int, by: str = "") -> Job:
    """Cancel a queued job at once; ask a running one to stop at its next checkpoint. Commits.
    `by` (the caller's name) goes into the job's message."""
    job = session.scalars(select(Job).where(Job.id == job_id).with_for_update()).first()
    if job is None:
        raise NotFound(f"job {job_id} not found")
    if job.status == "queued":
        job.status = "cancelled"
        job.finished_at = utcnow()
        job.message = "cancelled before it started" + (f" by {by}" if by else "")
    elif job.status == "running":
        job.cancel_requested = True
        job.message = "cancel requested" + (f" by {by}" if by else "")
    else:
        raise Conflict(f"job {job_id} is already {job.status}")
    session.commit()
    return job


# ----------------------------------------------------------------------------- tracks

TRACK_SORTS = {
    "id": Track.id,
    "length": Track.length,
    "n_samples": Track.n_samples,
    "n_points": Track.n_points,
    "mean_range": Track.mean_range,
    "confidence": Track.predicted_confidence,
    "updated_at": Track.updated_at,
    "first_frame": Track.first_frame,
}


@dataclass(frozen=True)
class TrackFilter:
    sequence_id: int | None = None
    status: str | None = None
    label: str | None = None
    unlabelled: bool | None = None
    min_length: int | None = None
    max_length: int | None = None
    predicted_class: str | None = None
    min_confidence: float | None = None
    max_confidence: float | None = None
    ids: tuple[int, ...] | None = None  # only these track ids (the viewer asks for a frame's tracks)

    def clauses(self) -> list[Any]:
        c: list[Any] = []
        if self.ids is not None:
            c.append(Track.id.in_(self.ids))
        if self.sequence_id is not None:
            c.append(Track.sequence_id == self.sequence_id)
        if self.status is not None:
            c.append(Track.status == self.status)
        if self.label is not None:
            c.append(Track.label == self.label)
        if self.unlabelled is True:
            c.append(Track.label.is_(None))
        elif self.unlabelled is False:
            c.append(Track.label.is_not(None))
        if self.min_length is not None:
            c.append(Track.length >= self.min_length)
        if self.max_length is not None:
            c.append(Track.length <= self.max_length)
        if self.predicted_class is not None:
            c.append(Track.predicted_class == self.predicted_class)
        if self.min_confidence is not None:
            c.append(Track.predicted_confidence >= self.min_confidence)
        if self.max_confidence is not None:
            c.append(Track.predicted_confidence <= self.max_confidence)
        return c


def list_tracks(
    session: Session, flt: TrackFilter, sort: str, limit: int, offset: int
) -> tuple[list[dict[str, Any]], int]:
    """A page of tracks (column dicts, no ORM objects: a page is read, never changed) and the total
    matching `flt`. `sort` is a key of TRACK_SORTS, '-' = descending."""
    desc = sort.startswith("-")
    col = TRACK_SORTS[sort.lstrip("-")]
    clauses = flt.clauses()
    # NULLs last either way, identically on both databases. Only a nullable column says so: an
    # explicit NULLS LAST on a column without NULLs changes no result but keeps PostgreSQL from
    # walking its index backwards (it sorted all 50k rows for every "-length" page)
    key = col.desc() if desc else col.asc()
    order = [key.nulls_last() if col.nullable else key, Track.id.desc() if desc else Track.id.asc()]
    # the page's ids first (sorting narrow index entries, not whole rows), then those rows
    page = select(Track.id).where(*clauses).order_by(*order).limit(limit).offset(offset)
    table = Track.__table__
    rows = session.connection().execute(select(table).where(table.c.id.in_(page)).order_by(*order)).mappings().all()
    total = session.scalar(select(func.count()).select_from(Track).where(*clauses)) or 0
    return [dict(r) for r in rows], int(total)


def get_track(session: Session, track_id: int) -> Track:
    track = session.get(Track, track_id)
    if track is None:
        raise NotFound(f"track {track_id} not found")
    return track


def track_segments(session: Session, track_id: int) -> list[Segment]:
    return list(
        session.scalars(select(Segment).where(Segment.track_id == track_id).order_by(Segment.frame_index)).all()
    )


def track_events(session: Session, track_id: int) -> list[AnnotationEvent]:
    return list(
        session.scalars(
            select(AnnotationEvent).where(AnnotationEvent.track_id == track_id).order_by(AnnotationEvent.id)
        ).all()
    )


REVIEW_FIELDS = ("status", "label", "keep_start", "keep_end")


def review_state(track: Track) -> dict[str, Any]:
    """The part of a track that actions change (what events record before and after)."""
    return {f: getattr(track, f) for f in REVIEW_FIELDS}


def initial_review_state(track: Track) -> dict[str, Any]:
    """The state a track had when ingest created it."""
    return {"status": "pending", "label": None, "keep_start": track.first_frame, "keep_end": track.last_frame}


def rebuild_review_state(session: Session, track: Track) -> dict[str, Any]:
    """The review state replayed from the event log alone (it must equal `review_state(track)`).
    A merge widens a track's frame range; its event records the range before (`range_before`),
    so the replay starts from the range ingest gave the track."""
    events = track_events(session, track.id)
    state = initial_review_state(track)
    for ev in events:
        if ev.detail and "range_before" in ev.detail:
            state["keep_start"], state["keep_end"] = ev.detail["range_before"]
            break
    for ev in events:
        if ev.before != state:
            raise Conflict(f"event log of track {track.id} is inconsistent at event {ev.id}")
        state = dict(ev.after)
    return state


def apply_action(
    session: Session,
    track_id: int,
    user: AuthUser,
    action: str,
    version: int,
    *,
    label: str | None = None,
    start: int | None = None,
    end: int | None = None,
    sample_classes: tuple[str, ...] = (),
    override_lease: bool = False,
    lease_seconds: float | None = None,
) -> Track:
    """Apply one review action if `version` is current; write its event; commit.

    Stale version -> Conflict (nothing changes); unknown class or bad range -> Invalid; another
    user's running lease -> LeaseHeld (409; see app.leases). The caller's own lease is renewed by
    `lease_seconds`.
    """
    track = _track_for_review(session, track_id, user, action, version, override_lease, lease_seconds)
    before = review_state(track)
    after, reverts = _review_after(session, track, user, action, before, label, start, end, sample_classes)
    if after["keep_start"] != before["keep_start"] or after["keep_end"] != before["keep_end"]:
        _recount_kept_range(session, track, after["keep_start"], after["keep_end"])

    now = utcnow()
    track.status, track.label = after["status"], after["label"]
    track.keep_start, track.keep_end = after["keep_start"], after["keep_end"]
    track.version = version + 1
    track.updated_at = now
    track.reviewed_by_id = user.id
    if after["status"] != "pending":
        track.lease_user_id, track.lease_expires_at = None, None
    session.flush()  # the track's UPDATE
    session.connection().execute(
        _INSERT_EVENT,
        {
            "track_id": track_id, "user_id": user.id, "action": action, "created_at": now,
            "version_before": version, "version_after": version + 1, "before": before, "after": after,
            "reverts_event_id": None if reverts is None else reverts.id,
        },
    )
    refresh_labels(session, track, user.id, sample_classes)
    session.commit()
    return track


def _track_for_review(
    session: Session, track_id: int, user: AuthUser, action: str, version: int, override_lease: bool,
    lease_seconds: float | None,
) -> Track:
    """The track, locked for update, once the action may go ahead: its sequence is ready, the
    lease allows it (renewing the caller's own), `version` is current and it is not merged away."""
    track = session.get(Track, track_id, with_for_update=True)
    if track is None:
        raise NotFound(f"track {track_id} not found")
    seq_status = session.connection().scalar(_SEQUENCE_STATUS, {"sequence_id": track.sequence_id})
    if seq_status != "ready":
        raise Conflict(f"sequence {track.sequence_id} is {seq_status}; tracks can be reviewed once it is ready")
    leases.check(session, track, user, utcnow(), override=override_lease, renew_seconds=lease_seconds)
    if track.version != version:
        raise Conflict(f"stale version {version}: track {track_id} is at version {track.version}")
    if track.status == "merged" and action != "undo":
        raise Conflict(f"track {track_id} was merged into another track; undo the merge first")
    return track


def _review_after(
    session: Session,
    track: Track,
    user: AuthUser,
    action: str,
    before: dict[str, Any],
    label: str | None,
    start: int | None,
    end: int | None,
    sample_classes: tuple[str, ...],
) -> tuple[dict[str, Any], AnnotationEvent | None]:
    """The review state after `action`, and the event an undo reverts (None for other actions)."""
    after = dict(before)
    reverts: AnnotationEvent | None = None
    if action == "accept":
        after["status"] = "accepted"
    elif action == "discard":
        after["status"] = "discarded"
    elif action == "label":
        if label not in sample_classes:
            raise Invalid(f"unknown class {label!r}; valid: {', '.join(sample_classes)}")
        after["label"] = label
        after["status"] = "accepted"  # labelling a track is accepting it with that class
    elif action == "truncate":
        assert start is not None and end is not None
        if not (track.first_frame <= start <= end <= track.last_frame):
            raise NotApplicable(
                f"frame range {start}..{end} is not inside the track's frames {track.first_frame}..{track.last_frame}"
            )
        after["keep_start"], after["keep_end"] = start, end
    elif action == "undo":
        reverts = last_undoable_event(session, track.id, user.id)
        if reverts is None:
            raise Conflict(f"nothing to undo: no action of {user.name} on track {track.id} is left to undo")
        for f in REVIEW_FIELDS:
            if reverts.before.get(f) != reverts.after.get(f):
                after[f] = reverts.before.get(f)
    else:
        raise Invalid(f"unknown action {action!r}")
    return after, reverts


def _recount_kept_range(session: Session, track: Track, keep_start: int, keep_end: int) -> None:
    """Set the track's length, samples, points and mean range from its segments in
    `keep_start..keep_end` (what ingest computes over the whole track). Invalid when none is kept."""
    length, n_samples, n_points, range_sum = session.execute(
        select(
            func.count(),
            func.coalesce(func.sum(Segment.valid.cast(Integer)), 0),
            func.coalesce(func.sum(Segment.n_points), 0),
            func.coalesce(func.sum(Segment.range), 0.0),
        ).where(Segment.track_id == track.id, Segment.frame_index.between(keep_start, keep_end))
    ).one()
    if length == 0:
        raise NotApplicable(f"frame range {keep_start}..{keep_end} keeps no segment of the track")
    track.length, track.n_samples = int(length), int(n_samples)
    track.n_points, track.mean_range = int(n_points), float(range_sum) / int(length)


def last_undoable_event(session: Session, track_id: int, user_id: int) -> AnnotationEvent | None:
    """The caller's latest non-undo event on the track that no undo has reverted yet."""
    reverted = select(AnnotationEvent.reverts_event_id).where(
        AnnotationEvent.track_id == track_id, AnnotationEvent.reverts_event_id.is_not(None)
    )
    return session.scalars(
        select(AnnotationEvent)
        .where(
            AnnotationEvent.track_id == track_id,
            AnnotationEvent.user_id == user_id,
            AnnotationEvent.action != "undo",
            AnnotationEvent.id.not_in(reverted),
        )
        .order_by(AnnotationEvent.id.desc())
        .limit(1)
    ).first()


# built once: an action runs these per call, and building a statement costs more than running it
_SEQUENCE_STATUS = select(Sequence.__table__.c.status).where(Sequence.__table__.c.id == bindparam("sequence_id"))
_INSERT_EVENT = insert(AnnotationEvent.__table__)
_DELETE_LABELS = delete(Label.__table__).where(Label.__table__.c.track_id == bindparam("track_id"))
_INSERT_LABELS = insert(Label.__table__).from_select(
    ["sequence_id", "segment_id", "track_id", "class_name", "class_index", "source", "user_id", "created_at"],
    select(
        Segment.sequence_id,
        Segment.id,
        Segment.track_id,
        bindparam("class_name", type_=String),
        bindparam("class_index", type_=Integer),
        literal("track"),
        bindparam("user_id", type_=Integer),
        bindparam("created_at", type_=DateTime),
    ).where(
        Segment.track_id == bindparam("track_id"),
        Segment.valid.is_(True),
        Segment.frame_index.between(bindparam("keep_start"), bindparam("keep_end")),
    ),
)


def refresh_labels(session: Session, track: Track, user_id: int, sample_classes: tuple[str, ...]) -> None:
    """Materialise the labelled samples of a track: its valid segments in the kept range when it is
    accepted with a class; none otherwise. (Core statements on the session's connection: no
    Label object is loaded in an action's session, so the ORM has nothing to synchronise.)"""
    conn = session.connection()
    conn.execute(_DELETE_LABELS, {"track_id": track.id})
    if track.status != "accepted" or track.label is None:
        return
    conn.execute(
        _INSERT_LABELS,
        {
            "track_id": track.id, "class_name": track.label, "class_index": sample_classes.index(track.label),
            "user_id": user_id, "created_at": utcnow(), "keep_start": track.keep_start, "keep_end": track.keep_end,
        },
    )


# ----------------------------------------------------------------------------- review queue


def _unleased(now: datetime) -> Any:
    """SQL condition: the track has no lease running at `now` (none, or an expired one)."""
    return or_(Track.lease_expires_at.is_(None), Track.lease_expires_at < now)


def lease_next_track(
    session: Session,
    user: AuthUser,
    lease_seconds: float,
    sequence_id: int | None = None,
    exclude: tuple[int, ...] = (),
) -> Track | None:
    """Lease a pending track of a ready sequence to `user`: their own live lease first, else the
    unleased (or lease-expired) pending track with the most samples. Tracks in `exclude` are
    passed over (one user's other viewer tabs hold them, or the operator skipped them). Commits."""
    now = utcnow()
    ready = select(Sequence.id).where(Sequence.status == "ready")
    base = [Track.status == "pending", Track.sequence_id.in_(ready)]
    if sequence_id is not None:
        base.append(Track.sequence_id == sequence_id)
    if exclude:
        base.append(Track.id.not_in(exclude))
    own = session.scalars(
        select(Track)
        .where(*base, Track.lease_user_id == user.id, Track.lease_expires_at > now)
        .order_by(Track.id)
        .limit(1)
        .with_for_update()
    ).first()
    track = own
    for _ in range(5):
        if track is not None:
            break
        cand = session.scalars(
            select(Track)
            .where(*base, _unleased(now))
            .order_by(Track.n_samples.desc(), Track.id)
            .limit(1)
            .with_for_update(skip_locked=True)
        ).first()
        if cand is None:
            session.rollback()
            return None
        # Conditional update: only wins if nobody leased it since we read it.
        res = session.execute(
            update(Track)
            .where(
                Track.id == cand.id,
                Track.status == "pending",
                _unleased(now),
            )
            .values(lease_user_id=user.id, lease_expires_at=now + timedelta(seconds=lease_seconds))
            .execution_options(synchronize_session=False)
        )
        if res.rowcount == 1:
            track = cand
    if track is None:
        session.rollback()
        return None
    track.lease_user_id = user.id
    track.lease_expires_at = now + timedelta(seconds=lease_seconds)
    session.commit()
    return track


def lease_track(session: Session, track_id: int, user: AuthUser, lease_seconds: float) -> Track:
    """Lease one chosen track to `user` (a track opened out of queue order, or brought back by
    undo), so that the queue does not hand it to someone else meanwhile. A reviewed track needs no
    lease and is returned as it is. NotFound for an unknown track; Conflict while another user's
    lease on it runs. Commits."""
    now = utcnow()
    track = session.get(Track, track_id)
    if track is None:
        raise NotFound(f"track {track_id} not found")
    if track.status != "pending":
        return track
    res = session.execute(
        update(Track)
        .where(
            Track.id == track_id,
            or_(Track.lease_user_id == user.id, _unleased(now)),
        )
        .values(lease_user_id=user.id, lease_expires_at=now + timedelta(seconds=lease_seconds))
        .execution_options(synchronize_session=False)
    )
    if res.rowcount != 1:
        session.rollback()
        holder = session.get(Track, track_id)
        name = session.scalar(select(User.name).where(User.id == holder.lease_user_id)) if holder else None
        until = holder.lease_expires_at.isoformat(timespec="seconds") if holder and holder.lease_expires_at else "?"
        raise Conflict(f"track {track_id} is being reviewed by {name or 'another operator'} (lease until {until})")
    session.commit()
    session.refresh(track)
    return track


def release_lease(session: Session, track_id: int, user: AuthUser) -> None:
    """Give back the caller's lease on a track (no-op when they hold none). Commits."""
    session.execute(
        update(Track)
        .where(Track.id == track_id, Track.lease_user_id == user.id)
        .values(lease_user_id=None, lease_expires_at=None)
    )
    session.commit()


# ----------------------------------------------------------------------------- ingest helpers


def clear_sequence_rows(session: Session, sequence_id: int) -> None:
    """Delete everything ingest wrote for a sequence (children first). Does not commit."""
    tracks = select(Track.id).where(Track.sequence_id == sequence_id)
    session.execute(delete(Label).where(Label.sequence_id == sequence_id))
    session.execute(delete(AnchorProposal).where(AnchorProposal.sequence_id == sequence_id))
    session.execute(delete(PairConstraint).where(PairConstraint.sequence_id == sequence_id))
    session.execute(delete(Stitch).where(Stitch.sequence_id == sequence_id))
    session.execute(update(AnnotationEvent).where(AnnotationEvent.track_id.in_(tracks)).values(reverts_event_id=None))
    session.execute(delete(AnnotationEvent).where(AnnotationEvent.track_id.in_(tracks)))
    session.execute(delete(Segment).where(Segment.sequence_id == sequence_id))
    session.execute(delete(Track).where(Track.sequence_id == sequence_id))
    session.execute(delete(Frame).where(Frame.sequence_id == sequence_id))


BULK_TABLES = ("tracks", "segments", "constraints", "stitches", "frames")


def analyze_tables(session: Session) -> None:
    """Refresh the planner's statistics after a bulk load (ingest): on SQLite, without them a filter
    on a low-cardinality column (status) is taken as selective and a 50k-row sort follows."""
    for table in BULK_TABLES:
        session.execute(text(f"ANALYZE {table}"))


def vacuum_after_bulk_load(engine: Engine) -> None:
    """PostgreSQL: VACUUM the freshly loaded tables (outside any transaction), so that their
    visibility map lets counts and id pages come from the indexes alone. Without it every
    `GET /tracks` counted 50k tracks by reading the whole table (6-7 ms) until autovacuum came by.
    Nothing to do on SQLite."""
    if engine.dialect.name != "postgresql":
        return
    with engine.connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
        conn.execute(text(f"VACUUM (ANALYZE) {', '.join(BULK_TABLES)}"))


# ----------------------------------------------------------------------------- statistics


def progress_stats(session: Session, sequence_id: int | None) -> dict[str, Any]:
    """Tracks by status, reviewed tracks, samples labelled per class, constraint counts."""
    t_where = [] if sequence_id is None else [Track.sequence_id == sequence_id]
    by_status = {
        k: int(v)
        for k, v in session.execute(
            select(Track.status, func.count()).where(*t_where).group_by(Track.status)
        ).all()
    }
    l_where = [] if sequence_id is None else [Label.sequence_id == sequence_id]
    per_class = {
        k: int(v)
        for k, v in session.execute(
            select(Label.class_name, func.count()).where(*l_where).group_by(Label.class_name)
        ).all()
    }
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

    def pair_columns(sa: Any, sb: Any, verified: Any) -> Any:
        return select(PairConstraint.id, PairConstraint.track_id, PairConstraint.segment_a_id,
                      PairConstraint.segment_b_id, sa.frame_index.label("frame_a"), sb.frame_index.label("frame_b"),
                      PairConstraint.score, verified.label("verified"))

    sa, sb = aliased(Segment), aliased(Segment)
    links = (
        pair_columns(sa, sb, Track.status == "accepted")
        .join(Track, Track.id == PairConstraint.track_id)
        .join(sa, sa.id == PairConstraint.segment_a_id)
        .join(sb, sb.id == PairConstraint.segment_b_id)
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
        pair_columns(fa, fb, frag_verified)
        .join(Stitch, Stitch.id == PairConstraint.stitch_id)
        .join(fa, fa.id == PairConstraint.segment_a_id)
        .join(fb, fb.id == PairConstraint.segment_b_id)
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


def track_label_rows(session: Session, sequence_id: int) -> list[Any]:
    """(track id, key, label, keep_start, keep_end) of accepted, labelled tracks."""
    return list(
        session.execute(
            select(Track.id, Track.key, Track.label, Track.keep_start, Track.keep_end).where(
                Track.sequence_id == sequence_id, Track.status == "accepted", Track.label.is_not(None)
            )
        ).all()
    )
