"""Stored images, as the JPEG bytes that were uploaded."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Response

from server.api.deps import PrincipalDep, ServicesDep

router = APIRouter(prefix="/images", tags=["images"])
ImageId = Annotated[int, Path(ge=1, le=2**63 - 1, description="Image id.")]


@router.get(
    "/{image_id}",
    response_class=Response,
    responses={200: {"content": {"image/jpeg": {}}, "description": "The JPEG bytes."}},
)
def get_image(image_id: ImageId, services: ServicesDep, _: PrincipalDep) -> Response:
    return Response(services.repo.image_jpeg(image_id), media_type="image/jpeg")
