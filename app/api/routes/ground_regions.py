"""Ground regions: the top view's lasso. An operator draws a polygon over a sequence's ground and
gives it a class of the sequence's label set; the ground points inside it take that class in
every frame (one action for a whole sidewalk or lawn), or with a height range every point inside
the prism (a hedge, a fence, whatever tracks it fell into). Deleting a region undoes it."""

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
    and `z_max` every point inside the prism (422 for a class outside the sequence's label set, a
    polygon without area, or one of z_min and z_max alone or out of order)."""
    return GroundRegionPublic.model_validate(
        crud.create_region(session, sequence_id, user, body.class_name, body.polygon, body.heights))


@router.delete("/ground-regions/{region_id}")
def delete_ground_region(region_id: IdPath, user: CurrentUser, session: WriteSessionDep) -> GroundRegionPublic:
    """Undo a ground region: its points go back to what the other sources give them."""
    return GroundRegionPublic.model_validate(crud.delete_region(session, region_id, user))
