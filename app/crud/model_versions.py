"""What the model jobs (`train`, `predict`, and issue 7's `finetune`, `propose_anchors`) share.

- `model_dir(settings, kind, job_id)`: where a job writes its checkpoints (under the data dir).
- `register_model_version(session, ...)`: one `model_versions` row for a trained checkpoint.
- `get_model_version(session, id)`: the row, or NotFound.
- `load_training_set(session, artifacts, sequence_ids, constraints=...)`: the labelled samples
  and constraint pairs of sequences, read from the labels/constraints tables and the frames'
  artifact files, as a `pipeline.training.TrainingData` plus the ids that tie it back to rows.
- `sample_config_for(settings, sequence)`: the sample settings the sequence was ingested with.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import ArtifactMissing, ArtifactStore
from app.core.config import Settings
from app.core.errors import Conflict, Invalid, NotFound
from app.crud.rows import get_or_404
from app.models import Frame, ModelVersion, Segment, Sequence, utcnow

if TYPE_CHECKING:
    from pipeline.config import SampleConfig
    from pipeline.training import TrainingData

ConstraintSource = Literal["verified", "automatic", "none"]


def model_dir(settings: Settings, kind: str, job_id: int | None) -> Path:
    """`<data_dir>/models/<kind>_<job id>` (a timestamp when there is no job)."""
    tag = f"{job_id:06d}" if job_id is not None else utcnow().strftime("%Y%m%dT%H%M%S%f")
    path = settings.data_dir / "models" / f"{kind}_{tag}"
    path.mkdir(parents=True, exist_ok=True)
    return path


def register_model_version(
    session: Session,
    *,
    name: str,
    kind: str,
    path: str | Path,
    metrics: dict[str, Any] | None = None,
    config: dict[str, Any] | None = None,
    parent_id: int | None = None,
    job_id: int | None = None,
    created_by_id: int | None = None,
) -> ModelVersion:
    """Insert a model version row (the caller commits). `path` must be an existing checkpoint;
    stored as given (absolute paths are clearest); metrics/config must be JSON-able."""
    p = Path(path)
    if not p.is_file():
        raise Invalid(f"checkpoint {p} does not exist")
    if parent_id is not None and session.get(ModelVersion, parent_id) is None:
        raise NotFound(f"model {parent_id} not found")
    mv = ModelVersion(
        name=name[:128],
        kind=kind[:32],
        path=str(p),
        config=config,
        metrics=metrics,
        parent_id=parent_id,
        job_id=job_id,
        created_by_id=created_by_id,
        created_at=utcnow(),
    )
    session.add(mv)
    session.flush()
    return mv


def list_model_versions(session: Session, kind: str | None, limit: int, offset: int) -> list[ModelVersion]:
    """Registered models, newest first (of one `kind` when given)."""
    q = select(ModelVersion).order_by(ModelVersion.id.desc()).limit(limit).offset(offset)
    if kind is not None:
        q = q.where(ModelVersion.kind == kind)
    return list(session.scalars(q).all())


def get_model_version(session: Session, model_id: int) -> ModelVersion:
    return get_or_404(session, ModelVersion, model_id, "model")


@dataclass(frozen=True)
class ChosenModel:
    """The model a job runs: a registered model version, or the shipped default (id None)."""

    id: int | None
    path: str

    @property
    def name(self) -> str:
        return "the default model" if self.id is None else f"model {self.id}"


def choose_model(session: Session, model_id: int | None) -> ChosenModel:
    """`model_id`'s model; None = the newest registered one, or the shipped default model
    (`pipeline.model.default_model_path`) while none is registered."""
    if model_id is not None:
        mv = get_model_version(session, model_id)
        return ChosenModel(mv.id, mv.path)
    mv = session.scalars(select(ModelVersion).order_by(ModelVersion.id.desc()).limit(1)).first()
    if mv is not None:
        return ChosenModel(mv.id, mv.path)
    from pipeline.errors import ConfigError
    from pipeline.model import default_model_path

    try:
        return ChosenModel(None, str(default_model_path()))
    except ConfigError as exc:
        raise NotFound(f"no model is registered and {exc}") from None


def newest_model_path(session: Session) -> str | None:
    """The checkpoint of the newest registered model, None while there is none."""
    return session.scalar(select(ModelVersion.path).order_by(ModelVersion.id.desc()).limit(1))


def _trained_on(mv: ModelVersion, sequence_id: int) -> bool:
    params = (mv.config or {}).get("params") or {}
    return sequence_id in (params.get("sequence_ids") or []) or params.get("sequence_id") == sequence_id


def newest_model_trained_on(session: Session, sequence_id: int) -> ModelVersion | None:
    """The newest model whose training job's params name the sequence (train's `sequence_ids`,
    finetune's `sequence_id`); None when no model was trained on it."""
    for mv in session.scalars(select(ModelVersion).order_by(ModelVersion.id.desc())):
        if _trained_on(mv, sequence_id):
            return mv
    return None


def model_version_for_job(session: Session, job_id: int) -> ModelVersion | None:
    """The model a job registered already (a retried job returns it instead of training again)."""
    return session.scalars(select(ModelVersion).where(ModelVersion.job_id == job_id).limit(1)).first()


def sample_config_for(settings: Settings, seq: Sequence) -> SampleConfig:
    """The sample settings of a sequence's ingest: the service's pipeline config + its overrides."""
    from pipeline.config import load_config

    cfg = load_config(settings.pipeline_config)
    if seq.config:
        cfg = cfg.override(seq.config)
    return cfg.samples


@dataclass(frozen=True)
class TrainingSet:
    """Training data read from the database.

    data:          samples (M, C, S, S) uint8, labelled indices + labels, pairs + weights.
    segment_ids:   (M,) int64 segment row id of each sample.
    track_ids:     (M,) int64 track row id of each sample (0 = none).
    pair_verified: (P,) bool, whether each pair lies on an accepted track.
    """

    data: TrainingData
    segment_ids: np.ndarray
    track_ids: np.ndarray
    pair_verified: np.ndarray

    @property
    def label_track_ids(self) -> np.ndarray:
        """(L,) track id of each labelled sample (for splits by track)."""
        return self.track_ids[self.data.labelled]


def ready_sequence(session: Session, sequence_id: int) -> Sequence:
    """The sequence, which the jobs that read its samples need ingested: NotFound / Conflict."""
    seq = session.get(Sequence, sequence_id)
    if seq is None:
        raise NotFound(f"sequence {sequence_id} not found")
    crud.check_ready(sequence_id, seq.status, "ingest it first")
    return seq


def _ready_sequences(session: Session, sequence_ids: list[int]) -> list[Sequence]:
    return [ready_sequence(session, sid) for sid in sequence_ids]


def stored_arrays(
    artifacts: ArtifactStore, refs: list[tuple[str, int]], names: tuple[str, ...]
) -> Iterator[tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]]:
    """Frame file by frame file, for `refs` [(artifact, sample index)]: (positions (n,) into `refs`,
    their sample indices (n,), the file's arrays `names`), once per file in the order the files
    first appear. Every reader of stored samples and their frames goes through here."""
    by_file: dict[str, list[tuple[int, int]]] = defaultdict(list)
    for pos, (artifact, index) in enumerate(refs):
        by_file[artifact].append((pos, index))
    for artifact, items in by_file.items():
        try:
            arrays = artifacts.read_arrays(artifact, names)
        except ArtifactMissing as exc:
            raise Conflict(str(exc)) from None
        src = np.array([i for _, i in items], np.int64)
        per_sample = next((arrays[k] for k in ("samples", "sample_segment") if k in arrays), None)
        if per_sample is not None and len(src) and src.max() >= len(per_sample):
            raise Conflict(f"artifact {artifact} holds {len(per_sample)} samples, a segment points at {src.max()}")
        yield np.array([d for d, _ in items], np.int64), src, arrays


def sample_chunks(
    artifacts: ArtifactStore, refs: list[tuple[str, int]]
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Stored samples frame file by frame file: for `refs` [(artifact, sample index)], yields
    (positions (n,) into `refs`, samples (n, C, S, S) uint8) once per frame file (`stored_arrays`)."""
    for dst, src, arrays in stored_arrays(artifacts, refs, ("samples",)):
        yield dst, arrays["samples"][src]


def read_samples(
    session: Session, artifacts: ArtifactStore, segment_ids: np.ndarray, progress: Any = None
) -> tuple[np.ndarray, np.ndarray]:
    """(samples (M, C, S, S) uint8, track ids (M,)) of segment rows, read frame file by frame file.

    progress(done, total) is called after each frame file.
    """
    rows = []
    ids = [int(v) for v in segment_ids]
    for i in range(0, len(ids), 5000):
        rows += session.execute(
            select(Segment.id, Segment.sample_index, Segment.track_id, Frame.artifact)
            .join(Frame, Frame.id == Segment.frame_id)
            .where(Segment.id.in_(ids[i : i + 5000]))
        ).all()
    if len(rows) != len(set(ids)):
        raise NotFound(f"{len(set(ids)) - len(rows)} segment(s) not found")
    pos = {sid: k for k, sid in enumerate(ids)}
    refs: list[tuple[str, int]] = [("", 0)] * len(ids)
    track = np.zeros(len(ids), np.int64)
    for seg_id, sample_index, track_id, artifact in rows:
        if sample_index is None:
            raise Invalid(f"segment {seg_id} has no sample (not a valid segment)")
        refs[pos[int(seg_id)]] = (artifact, int(sample_index))
        track[pos[int(seg_id)]] = track_id or 0
    n_files = len({a for a, _ in refs})
    out: np.ndarray | None = None
    for done, (dst, samples) in enumerate(sample_chunks(artifacts, refs), 1):
        if out is None:
            out = np.zeros((len(ids), *samples.shape[1:]), np.uint8)
        elif samples.shape[1:] != out.shape[1:] and len(samples):
            raise Conflict(f"samples of {len(samples)} segments are {samples.shape[1:]}, others {out.shape[1:]}")
        out[dst] = samples
        if progress is not None:
            progress(done, n_files)
    if out is None:
        out = np.zeros((0, 4, 1, 1), np.uint8)
    return out, track


@dataclass(frozen=True)
class Scores:
    """probs: (N, K) float32 class probabilities; features: (N, D) float32 embeddings or None."""

    probs: np.ndarray
    features: np.ndarray | None


def score_stored_samples(
    artifacts: ArtifactStore,
    refs: list[tuple[str, int]],
    model: Any,
    model_name: str,
    batch: int,
    features: bool = False,
    on_file: Callable[[int, int], None] | None = None,
) -> Scores:
    """Run stored samples [(artifact, sample index)] through `model` (a SampleCNN), at least
    `batch` samples per forward; on_file(done, total) after each frame file. Samples of another
    shape than the model reads are an Invalid naming both."""
    from pipeline.model import embed, predict

    cfg = model.config
    want = (cfg.in_channels, cfg.size, cfg.size)
    probs = np.zeros((len(refs), cfg.num_classes), np.float32)
    feats = np.zeros((len(refs), model.feature_dim), np.float32) if features else None
    pending: list[tuple[np.ndarray, np.ndarray]] = []

    def flush() -> None:
        if not pending:
            return
        dst = np.concatenate([d for d, _ in pending])
        x = np.concatenate([x for _, x in pending])  # (n, C, S, S)
        probs[dst] = predict(model, x, batch)
        if feats is not None:
            feats[dst] = embed(model, x, batch)
        pending.clear()

    n_files = len({a for a, _ in refs})
    for done, (dst, samples) in enumerate(sample_chunks(artifacts, refs), 1):
        if samples.shape[1:] != want:
            raise Invalid(f"the sequence has {tuple(samples.shape[1:])} samples, {model_name} reads {want} "
                          "(channels, size, size): re-ingest the sequence with the model's sample size")
        pending.append((dst, samples))
        if sum(len(d) for d, _ in pending) >= batch:
            flush()
        if on_file is not None:
            on_file(done, n_files)
    flush()
    return Scores(probs, feats)


def load_training_set(
    session: Session,
    artifacts: ArtifactStore,
    sequence_ids: list[int],
    constraints: ConstraintSource = "verified",
    min_score: float = 0.0,
    classes: tuple[str, ...] | None = None,
    progress: Any = None,
) -> TrainingSet:
    """Labelled samples (the labels table) and must-link pairs of the given ready sequences.

    constraints: "verified" = pairs inside the kept range of accepted tracks, weight 1 (the paper);
      "automatic" = pairs of every non-discarded track with score >= min_score, weighted by the
      association score (accepted tracks' pairs weigh 1); "none" = labels only.
    Pairs of tracks labelled "unknown" are kept: they join views of one object like any other
    track's (the paper makes none; `tracklabel experiment paper` measured constraint100 better with
    them, its ablation constraint100_no_unknown).
    classes: the model's class table (default: the sample classes of the sequences' one label set);
      labels outside it are an error.
    """
    from pipeline.training import TrainingData

    classes = classes or crud.common_label_set(session, sequence_ids).sample_class_names
    seqs = _ready_sequences(session, sequence_ids)
    lab_seg: list[int] = []
    lab_cls: list[int] = []
    pair_rows: list[tuple[int, int, float, bool]] = []
    for seq in seqs:
        for seg_id, _track, _frame, class_name, _idx in session.execute(crud.labels_query(seq.id)).all():
            if class_name not in classes:
                raise Invalid(f"label {class_name!r} of segment {seg_id} is not a class of the model ({', '.join(classes)})")
            lab_seg.append(int(seg_id))
            lab_cls.append(classes.index(class_name))
        if constraints != "none":
            q = crud.constraints_query(seq.id, verified_only=constraints == "verified")
            for row in session.execute(q).all():
                verified = bool(row.verified)
                score = float(row.score)
                if not verified and score < min_score:
                    continue
                pair_rows.append((int(row.segment_a_id), int(row.segment_b_id), 1.0 if verified else score, verified))
    seg_ids = np.unique(np.array(lab_seg + [a for a, *_ in pair_rows] + [b for _, b, *_ in pair_rows], np.int64))
    if len(seg_ids) == 0:
        raise Invalid(f"sequences {sequence_ids} hold no labels and no constraints to train on")
    samples, track = read_samples(session, artifacts, seg_ids, progress)
    where = {int(s): i for i, s in enumerate(seg_ids)}
    labelled = np.array([where[s] for s in lab_seg], np.int64)
    pairs = np.array([[where[a], where[b]] for a, b, *_ in pair_rows], np.int64).reshape(-1, 2)
    weights = np.array([w for *_, w, _v in pair_rows], np.float32)
    verified = np.array([v for *_, v in pair_rows], bool)
    data = TrainingData.build(samples, labelled, np.array(lab_cls, np.int64), pairs, weights)
    return TrainingSet(data, seg_ids, track, verified)
