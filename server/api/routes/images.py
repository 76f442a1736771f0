"""Stored images, as the JPEG bytes that were uploaded."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Response

from server.api.deps import HouseholdDep, ServicesDep
from server.schemas import MAX_ID

router = APIRouter(prefix="/images", tags=["images"])
ImageId = Annotated[int, Path(ge=1, le=MAX_ID, description="Image id.")]


@router.get(
    "/{image_id}",
    response_class=Response,
    responses={200: {"content": {"image/jpeg": {}}, "description": "The JPEG bytes."}},
)
def get_image(image_id: ImageId, services: ServicesDep, household: HouseholdDep) -> Response:
    """A stored image of the caller's household."""
    return Response(services.tours.image_jpeg(image_id, household), media_type="image/jpeg")
