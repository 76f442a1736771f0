"""Tours: create, list, read the graph."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Response, status

from server import schemas
from server.api.deps import HouseholdDep, ServicesDep

router = APIRouter(prefix="/tours", tags=["tours"])
PathId = Annotated[int, Path(ge=1, le=schemas.MAX_ID, description="Tour id.")]


@router.post("", status_code=status.HTTP_201_CREATED, response_model=schemas.TourSummary)
def create_tour(
    body: schemas.TourCreate, services: ServicesDep, household: HouseholdDep
) -> schemas.TourSummary:
    """Create an empty tour in the caller's household; teach it with
    POST /robots/{robot}/teach/start."""
    return services.tours.create(body, household)


@router.get("", response_model=list[schemas.TourSummary])
def list_tours(services: ServicesDep, household: HouseholdDep) -> list[schemas.TourSummary]:
    """The tours of the caller's household."""
    return services.tours.list(household)


@router.get("/{tour_id}", response_model=schemas.TourGraphPublic)
def get_tour(
    tour_id: PathId, services: ServicesDep, household: HouseholdDep
) -> schemas.TourGraphPublic:
    """The tour's graph: locations with their images, edges with counts and durations."""
    return services.tours.graph(tour_id, household)


ChangeId = Annotated[int, Path(ge=1, le=schemas.MAX_ID, description="Learned change id.")]


@router.get("/{tour_id}/learned", response_model=list[schemas.LearnedChange])
def list_learned(
    tour_id: PathId, services: ServicesDep, household: HouseholdDep
) -> list[schemas.LearnedChange]:
    """What the tour learned from answered questions (docs/learning.md): each change, when,
    from which question; remove one by deleting /tours/{tour_id}/learned/{change_id}."""
    return services.questions.changes(tour_id, household)


@router.delete("/{tour_id}/learned/{change_id}", status_code=status.HTTP_204_NO_CONTENT)
def remove_learned(
    tour_id: PathId, change_id: ChangeId, services: ServicesDep, household: HouseholdDep
) -> Response:
    """Undo one learned change: the tour behaves as if it had never been learned."""
    services.questions.remove_change(tour_id, change_id, household)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
