"""Stored images, as the JPEG bytes that were uploaded."""

from __future__ import annotations

from fastapi import APIRouter, Response

from server.api.deps import PrincipalDep, ServicesDep

router = APIRouter(prefix="/images", tags=["images"])


@router.get(
    "/{image_id}",
    response_class=Response,
    responses={200: {"content": {"image/jpeg": {}}, "description": "The JPEG bytes."}},
)
def get_image(image_id: int, services: ServicesDep, _: PrincipalDep) -> Response:
    return Response(services.repo.image_jpeg(image_id), media_type="image/jpeg")
