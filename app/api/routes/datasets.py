from __future__ import annotations

from fastapi import APIRouter, status

from app import crud
from app.api.deps import AdminUser, CurrentUser, IdPath, SessionDep, SettingsDep, WriteSessionDep
from app.core.errors import Conflict, Invalid
from app.crud import AuthUser
from app.crud.ingest_rows import note_queued
from app.jobs import policy
from app.jobs.registry import get_job_type
from app.models import Dataset, Job, Sequence
from app.schemas import (
    DatasetCreate,
    DatasetDetail,
    DatasetPublic,
    IngestRequest,
    JobPublic,
    LabelSetPublic,
    SequencePublic,
    SequenceStats,
    SequenceStatus,
)
from app.services.label_sets import registration_label_set

router = APIRouter(tags=["datasets"])


def _public(session: SessionDep, ds: Dataset) -> DatasetPublic:
    seqs = crud.dataset_sequences(session, ds.id)
    return DatasetPublic(
        id=ds.id,
        name=ds.name,
        path=ds.path,
        created_at=ds.created_at,
        sequences=[SequencePublic.model_validate(s) for s in seqs],
    )


def _queue_ingest(session: WriteSessionDep, sequence_id: int, force: bool, user_id: int, poses: str = "file") -> Job:
    ingest = get_job_type("ingest")
    params = ingest.params.model_validate({"sequence_id": sequence_id, "force": force, "poses": poses})
    assert ingest.prepare is not None
    ingest.prepare(session, params)
    job = crud.create_job(session, "ingest", params.model_dump(mode="json"), user_id, policy.ADMIN_PRIORITY)
    note_queued(session, sequence_id, job.id)
    return job


@router.post("/datasets", status_code=status.HTTP_201_CREATED)
def register_dataset(
    body: DatasetCreate, admin: AdminUser, session: WriteSessionDep, settings: SettingsDep
) -> DatasetPublic:
    """Register a sequence by its path under a configured data root (admin).

    A path with `..`, outside the roots, or holding a link to outside them (however many hops),
    a hard link to a file outside them, or a config whose sensor file lies outside is refused
    with 403; a
    folder registered before with 409 and the existing `sequence_id` (unless `reregister`). With
    `ingest` (default) the ingest job is queued at once; its id is the sequence's `ingest_job_id`.
    """
    from pipeline.errors import TracklabelError
    from pipeline.io.registry import detect_format, reader_names

    path = crud.resolve_registration_path(body.path, settings.data_roots)
    crud.check_tree_inside_roots(path, settings.data_roots)
    existing = crud.registered_sequence_id(session, path)
    if existing is not None and not body.reregister:
        raise Conflict(
            f"this folder is already registered as sequence {existing}; pass reregister=true to register it again",
            sequence_id=existing,
        )
    if body.format != "auto" and body.format not in reader_names():
        raise Invalid(f"unknown format {body.format!r}; known: {', '.join(reader_names())}")
    if body.config:
        from pipeline.config import PipelineConfig

        try:
            config = PipelineConfig().override(body.config)
        except TracklabelError as exc:
            raise Invalid(f"config: {exc}") from exc
        crud.check_sensor_file(config, settings.data_roots)
    try:
        fmt = detect_format(path) if body.format == "auto" else body.format
    except TracklabelError as exc:
        raise Invalid(str(exc)) from exc
    label_set, definition = registration_label_set(body.label_set)
    ds, seq = crud.create_dataset(session, path, body.name, fmt, body.config, admin.id, label_set.name, definition)
    if body.ingest:
        _queue_ingest(session, seq.id, False, admin.id, body.poses)
    session.commit()
    return _public(session, ds)


@router.get("/datasets")
def list_datasets(_admin: AdminUser, session: SessionDep) -> list[DatasetPublic]:
    """Registered datasets with their paths and sequences (admin)."""
    return [_public(session, ds) for ds in crud.list_datasets(session)]


@router.get("/datasets/{dataset_id}")
def inspect_dataset(dataset_id: IdPath, _admin: AdminUser, session: SessionDep) -> DatasetDetail:
    """A dataset with per-sequence counts of frames, segments, samples, tracks and constraints (admin)."""
    pub = _public(session, crud.get_dataset(session, dataset_id))
    stats = []
    for sp in pub.sequences:
        seq = crud.get_sequence(session, sp.id)
        stats.append(SequenceStats(sequence=sp, **crud.sequence_stats(session, seq)))
    return DatasetDetail(**pub.model_dump(), stats=stats)


@router.get("/sequences")
def list_sequences(
    user: CurrentUser, session: SessionDep, status: SequenceStatus | None = None
) -> list[SequencePublic]:
    """Sequences to review (any user; the folder `path` only for admins)."""
    return [_sequence_public(s, user) for s in crud.list_sequences(session, status)]


def _sequence_public(seq: Sequence, user: AuthUser) -> SequencePublic:
    pub = SequencePublic.model_validate(seq)
    return pub if user.is_admin else pub.model_copy(update={"path": None})


@router.get("/sequences/{sequence_id}")
def read_sequence(sequence_id: IdPath, user: CurrentUser, session: SessionDep) -> SequencePublic:
    """One sequence: format, sensor, ingest status (and its path, for admins)."""
    return _sequence_public(crud.get_sequence(session, sequence_id), user)


@router.get("/sequences/{sequence_id}/label-set")
def read_sequence_label_set(sequence_id: IdPath, _user: CurrentUser, session: SessionDep) -> LabelSetPublic:
    """The sequence's label set: its classes with their colours, hotkeys and SemanticKITTI ids (what
    the annotator's class buttons show, and the classes its tracks can take)."""
    return LabelSetPublic.of(crud.label_set_of(crud.get_sequence(session, sequence_id)))


@router.post("/sequences/{sequence_id}/ingest", status_code=status.HTTP_202_ACCEPTED)
def ingest_sequence(
    sequence_id: IdPath, body: IngestRequest, admin: AdminUser, session: WriteSessionDep
) -> JobPublic:
    """Queue the ingest job of a sequence (admin). `force` redoes a ready sequence and drops its
    reviews; `poses` is `file` (the sequence's own) or `icp` (estimated)."""
    job = _queue_ingest(session, sequence_id, body.force, admin.id, body.poses)
    session.commit()
    return JobPublic.model_validate(job)
