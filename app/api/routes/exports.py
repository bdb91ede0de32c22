from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query, Response
from fastapi.responses import StreamingResponse

from app import crud
from app.api.deps import ArtifactsDep, CurrentUser, IdPath, SessionDep
from app.crud import audits
from app.schemas import ProgressStats
from app.services import exports
from app.services.point_labels import ExportOptions, point_label_plan
from pipeline.propagation import Rules

router = APIRouter(prefix="/exports", tags=["exports"])

SeqQuery = Annotated[int | None, Query(ge=1, le=2**31 - 1, description="One sequence; all when omitted.")]
Format = Literal["jsonl", "npz"]


@router.get(
    "/constraints",
    response_class=Response,
    responses={200: {"content": {"application/x-ndjson": {}, "application/x-npz": {}}}},
)
def export_constraints(
    _user: CurrentUser,
    session: SessionDep,
    artifacts: ArtifactsDep,
    sequence_id: SeqQuery = None,
    verified_only: bool = True,
    format: Format = "jsonl",
) -> Response:
    """Must-link pairs of samples with their association scores, inside the kept range of tracks
    that are not discarded: only accepted tracks' (verified) by default, or with the automatic ones.
    `jsonl`: one pair per line; `npz`: samples, sample_segment, pairs (P,2), score, verified, track_id."""
    if format == "npz":
        rows = exports.constraint_rows(session, sequence_id, verified_only)
        return Response(exports.constraints_npz(session, artifacts, rows), media_type="application/x-npz")
    lines = exports.constraint_lines(session, sequence_id, verified_only)
    return StreamingResponse(exports.constraints_jsonl(lines), media_type="application/x-ndjson")


@router.get(
    "/labels",
    response_class=Response,
    responses={200: {"content": {"application/x-ndjson": {}, "application/x-npz": {}}}},
)
def export_labels(
    _user: CurrentUser,
    session: SessionDep,
    artifacts: ArtifactsDep,
    sequence_id: SeqQuery = None,
    format: Format = "jsonl",
) -> Response:
    """Labelled samples (valid samples in the kept range of accepted, labelled tracks).
    `npz`: samples, label (class index), segment_id, track_id, frame_index."""
    rows = exports.label_rows(session, sequence_id)
    if format == "npz":
        return Response(exports.labels_npz(session, artifacts, rows), media_type="application/x-npz")
    return StreamingResponse(exports.jsonl(rows), media_type="application/x-ndjson")


@router.get(
    "/semantickitti/{sequence_id}",
    response_class=StreamingResponse,
    responses={200: {"content": {"application/x-tar": {}}}},
)
def export_semantickitti(
    sequence_id: IdPath,
    _user: CurrentUser,
    session: SessionDep,
    artifacts: ArtifactsDep,
    include_ground: bool = False,
    reviewed_only: bool = False,
    radius: Annotated[float, Query(ge=0.0, le=5.0, description="Metres labels travel to points no review reached.")] = Rules.radius,
    ground_radius: Annotated[float, Query(ge=0.0, le=5.0, description="The same, to points the ground estimate took.")]
    = Rules.ground_radius,
    far_radius: Annotated[float, Query(ge=0.0, le=20.0, description="Metres, within a frame, to points that are not "
                                       "ground and that nothing reached within `radius`.")] = Rules.far_radius,
    region_radius: Annotated[float, Query(ge=0.0, le=5.0, description="Metres, within a frame, from the points that a "
                                          "region without heights gave an object class to points that are not ground "
                                          "and that no decided point reached.")] = Rules.region_radius,
    with_sources: bool = False,
) -> StreamingResponse:
    """Per-frame SemanticKITTI `.label` files as a streamed tar, a class for every point that any
    source reaches: its track's reviewed or bulk-accepted class, else the nearest decided point
    within `radius` (in the world frame, this or nearby frames), else (points that are not ground)
    the nearest point of its frame that a region without heights gave an object class (within
    `region_radius`), else its track's predicted class
    or its frame's nearest labelled point (within `far_radius`); instance = track key (chunked
    with `chunk_map.json` past 65,535). `include_ground` writes the ground class on the remaining
    ground points; `reviewed_only` keeps the reviewed tracks' points alone. `summary.json` counts
    the points per source and class, with confidences, and the points left without a class;
    `with_sources` adds each point's source (`sources/<frame>.source`, uint8 per row: its index in
    `summary.sources`)."""
    seq = crud.get_sequence(session, sequence_id)
    rules = Rules(radius=radius, ground_radius=ground_radius, far_radius=far_radius,
                  region_radius=region_radius)
    options = ExportOptions(include_ground, reviewed_only, rules)
    plan = point_label_plan(session, seq, options)
    session.close()
    return StreamingResponse(
        exports.semantickitti_tar(plan, artifacts, with_sources),
        media_type="application/x-tar",
        headers={"Content-Disposition": f'attachment; filename="labels_{sequence_id}.tar"'},
    )


@router.get("/stats")
def export_stats(_user: CurrentUser, session: SessionDep, sequence_id: SeqQuery = None) -> ProgressStats:
    """Progress: tracks by status and reviewed, samples labelled per class, constraint counts, and
    the audits' agreement per operator and per class; for one sequence, its label set and classes."""
    label_set = crud.sequence_label_set(session, sequence_id)
    classes = [] if label_set is None else list(label_set.sample_class_names)
    return ProgressStats(**crud.progress_stats(session, sequence_id), label_set=None if label_set is None else label_set.name,
                         classes=classes,
                         audit=audits.audit_stats(session, sequence_id))
