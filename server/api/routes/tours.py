"""Tours: create, list, read the graph."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, status

from server import schemas
from server.api.deps import PrincipalDep, ServicesDep

router = APIRouter(prefix="/tours", tags=["tours"])
PathId = Annotated[int, Path(ge=1, le=2**63 - 1, description="Tour id.")]


@router.post("", status_code=status.HTTP_201_CREATED, response_model=schemas.TourSummary)
def create_tour(
    body: schemas.TourCreate, services: ServicesDep, _: PrincipalDep
) -> schemas.TourSummary:
    """Create an empty tour; teach it with POST /robots/{robot}/teach/start."""
    return services.tours.create(body)


@router.get("", response_model=list[schemas.TourSummary])
def list_tours(services: ServicesDep, _: PrincipalDep) -> list[schemas.TourSummary]:
    return services.tours.list()


@router.get("/{tour_id}", response_model=schemas.TourGraphPublic)
def get_tour(tour_id: PathId, services: ServicesDep, _: PrincipalDep) -> schemas.TourGraphPublic:
    """The tour's graph: locations with their images, edges with counts and durations."""
    return services.tours.graph(tour_id)
