"""Ground regions: the top view's lasso. An operator draws a polygon over a sequence's ground and
gives it a class of the sequence's label set; the ground points inside it take that class in
every frame (one action for a whole sidewalk or lawn), or with a height range every point inside
the prism (a hedge, a fence, whatever tracks it fell into), or, drawn in one frame's view, every
point of that frame inside the lasso (the last points nothing else separates). Deleting a region
undoes it."""

from __future__ import annotations

from fastapi import APIRouter

from app import crud
from app.api.deps import CurrentUser, IdPath, SessionDep, WriteSessionDep
from app.schemas import GroundRegionCreate, GroundRegionPublic

router = APIRouter(tags=["review"])


@router.get("/sequences/{sequence_id}/ground-regions")
def list_ground_regions(sequence_id: IdPath, _user: CurrentUser, session: SessionDep) -> list[GroundRegionPublic]:
    """The sequence's ground regions, oldest first (later ones are drawn over earlier ones)."""
    crud.get_sequence(session, sequence_id)
    return [GroundRegionPublic.model_validate(r) for r in crud.list_regions(session, sequence_id)]


@router.post("/sequences/{sequence_id}/ground-regions")
def create_ground_region(sequence_id: IdPath, body: GroundRegionCreate, user: CurrentUser,
                         session: WriteSessionDep) -> GroundRegionPublic:
    """Label the ground points inside `polygon`, in every frame, as `class_name`, or with `z_min`
    and `z_max` every point inside the prism; with `frame_index` in that frame only, and with
    `clip_from_world` every point of that frame inside the lasso drawn in its view (422 for a
    class outside the sequence's label set, a polygon without area, one of z_min and z_max alone
    or out of order, a frame the sequence lacks, or a view without its frame)."""
    return GroundRegionPublic.model_validate(
        crud.create_region(session, sequence_id, user, body.class_name, body.polygon, body.heights,
                           body.frame_index, body.clip_from_world))


@router.delete("/ground-regions/{region_id}")
def delete_ground_region(region_id: IdPath, user: CurrentUser, session: WriteSessionDep) -> GroundRegionPublic:
    """Undo a ground region: its points go back to what the other sources give them."""
    return GroundRegionPublic.model_validate(crud.delete_region(session, region_id, user))
