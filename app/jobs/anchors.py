"""`propose_anchors`: a model scores every sample of a sequence and proposes anchors to confirm.

1. Load the model version's checkpoint; read the samples of the sequence's valid segments frame
   file by frame file, scoring them as it goes (class probabilities, and CNN features for the
   k-center strategies), so memory holds scores, never the whole sequence's canvases.
2. Leave out what needs no proposal: samples of labelled or discarded tracks, and samples (or
   for track strategies, tracks) of proposals already answered. With `replace` (the default) the
   sequence's unanswered proposals are deleted first; answering one of those later gets 404.
3. `pipeline.anchors.propose` picks `per_class` proposals per class (`unknown` for unknown) with
   the strategy; each becomes an `anchor_proposals` row: level `sample` (one segment) or
   `track` (the whole track, with a representative segment to show).
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import ConfigDict, Field

from app.core.errors import Invalid
from app.crud.anchors import answered_proposals, proposal_candidates, store_proposals
from app.crud.model_versions import choose_model, ready_sequence, score_stored_samples
from app.jobs.context import JobContext
from app.jobs.policy import OperatorRule
from app.jobs.registry import JobType, register
from app.models import utcnow
from app.schemas import JsonModel

Strategy = Literal["confident", "entropy", "diverse", "track", "track_diverse"]


class ProposeAnchorsParams(JsonModel):
    model_config = ConfigDict(extra="forbid")
    sequence_id: int = Field(ge=1, le=2**31 - 1)
    model_id: int | None = Field(default=None, ge=1, le=2**31 - 1,
                                 description="None = the newest model, or the shipped default model while none is registered.")
    strategy: Strategy = Field(default="track_diverse", description="See pipeline/anchors.py.")
    per_class: int = Field(default=20, ge=0, le=10_000, description="Proposals per class (tracks for track strategies).")
    unknown: int = Field(default=100, ge=0, le=10_000, description="Proposals for the label set's fallback class "
                         "(unknown in the default set: what no other class fits).")
    min_track_samples: int = Field(default=3, ge=1, le=10_000, description="Track strategies prefer tracks this long.")
    replace: bool = Field(default=True, description="Delete the sequence's unanswered proposals first.")
    batch: int = Field(default=256, ge=1, le=65_536)


def prepare_propose(s: Any, params: ProposeAnchorsParams) -> None:
    from app.crud.label_sets import label_set_of
    from app.services.label_sets import require_model_label_set

    seq = ready_sequence(s, params.sequence_id)
    chosen = choose_model(s, params.model_id)
    require_model_label_set(chosen.name, chosen.path, label_set_of(seq))


def _excluded(rows: list[Any], answered: list[Any], track_level: bool) -> np.ndarray:
    """(N,) bool: samples not to propose: of discarded or labelled tracks, answered already (and
    with a track strategy, of tracks answered already)."""
    seg_ids = np.array([r[0] for r in rows], np.int64)
    exclude = np.array([(r[4] == "discarded") or (r[5] is not None) for r in rows], bool)
    done_segments = {int(a) for a, _t, lvl in answered if a is not None and lvl == "sample"}
    exclude |= np.isin(seg_ids, list(done_segments))
    if track_level:
        done_tracks = {int(t) for _a, t, lvl in answered if lvl == "track"}
        exclude |= np.isin(np.array([r[1] for r in rows], np.int64), list(done_tracks))
    return exclude


def _proposal_rows(ctx: JobContext, params: ProposeAnchorsParams, out: Any, classes: tuple[str, ...],
                   seg_ids: np.ndarray, track_ids: np.ndarray, mv_id: int | None, level: str) -> list[dict[str, Any]]:
    """The anchor_proposals rows of `out` (pipeline.anchors.Proposals), ranked within each class."""
    rank = np.zeros(len(out), np.int64)
    for k in range(len(classes)):
        m = out.proposed == k
        rank[m] = np.arange(int(m.sum()))
    now = utcnow()
    return [
        {
            "sequence_id": params.sequence_id,
            "track_id": int(track_ids[i]),
            "segment_id": int(seg_ids[i]),
            "model_version_id": mv_id,
            "proposed_class": classes[int(k)],
            "score": float(sc),
            "status": "proposed",
            "level": level,
            "strategy": params.strategy,
            "rank": int(r),
            "job_id": ctx.job_id,
            "created_at": now,
        }
        for i, k, sc, r in zip(out.index, out.proposed, out.score, rank, strict=True)
    ]


def run_propose(ctx: JobContext, params: ProposeAnchorsParams) -> dict[str, Any]:
    from app.crud.label_sets import label_set_of
    from app.services.label_sets import check_model_label_set
    from pipeline.anchors import TRACK_STRATEGIES, class_counts, propose
    from pipeline.model import load_checkpoint

    with ctx.db.read() as s:
        label_set = label_set_of(ready_sequence(s, params.sequence_id))
        chosen = choose_model(s, params.model_id)
        mv_id, mv_path = chosen.id, chosen.path
        rows = proposal_candidates(s, params.sequence_id)
        answered = answered_proposals(s, params.sequence_id, with_unanswered=not params.replace)
    if not rows:
        raise Invalid(f"sequence {params.sequence_id} has no samples on tracks to propose")
    ctx.progress(0.0, f"scoring {len(rows)} samples with {chosen.name}")
    model, meta = load_checkpoint(mv_path)
    check_model_label_set(chosen.name, meta, mv_path, label_set)  # as prepare_propose does at queue time
    classes = tuple(meta.classes[: meta.model_config.num_classes])
    if meta.sample_config.channels != model.config.in_channels:  # pragma: no cover - load_checkpoint checks
        raise Invalid(f"{chosen.name}: inconsistent checkpoint")

    seg_ids = np.array([r[0] for r in rows], np.int64)
    track_ids = np.array([r[1] for r in rows], np.int64)

    def scored(done: int, total: int) -> None:
        if done % 20 == 0:
            ctx.progress(0.9 * done / total, f"scored frame {done}/{total}")

    scores = score_stored_samples(ctx.artifacts, [(r[3], int(r[2])) for r in rows], model, chosen.name, params.batch,
                                  features=params.strategy in ("diverse", "track_diverse"), on_file=scored)
    probs, feats = scores.probs, scores.features

    exclude = _excluded(rows, answered, params.strategy in TRACK_STRATEGIES)
    counts = class_counts(params.per_class, params.unknown, classes, fallback=label_set.fallback)
    out = propose(probs, params.strategy, counts, features=feats, tracks=track_ids, exclude=exclude,
                  min_track_samples=params.min_track_samples)
    level = "track" if params.strategy in TRACK_STRATEGIES else "sample"
    values = _proposal_rows(ctx, params, out, classes, seg_ids, track_ids, mv_id, level)
    ctx.checkpoint()
    with ctx.db.write() as s:
        removed = store_proposals(s, params.sequence_id, values, replace=params.replace)
    per_class = out.per_class(len(classes))
    return {
        "sequence_id": params.sequence_id,
        "model_id": mv_id,
        "strategy": params.strategy,
        "level": level,
        "samples_scored": len(rows),
        "samples_excluded": int(exclude.sum()),
        "proposals": len(values),
        "per_class": {classes[k]: int(per_class[k]) for k in range(len(classes))},
        "replaced": removed,
    }


register(
    JobType(
        name="propose_anchors",
        params=ProposeAnchorsParams,
        handler=run_propose,
        admin_only=False,
        description="Score a sequence's samples with a model and propose anchors (per class) to confirm.",
        prepare=prepare_propose,
        operator_rule=OperatorRule(max_values={"per_class": 200, "unknown": 500, "batch": 1024, "min_track_samples": 1000}),
        max_run_seconds=1800.0,
    )
)
