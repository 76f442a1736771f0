"""The HTTP client a robot (or a script) uses, typed with the server's wire schemas."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, TypeVar

import httpx
from pydantic import BaseModel, TypeAdapter

from server import schemas

M = TypeVar("M", bound=BaseModel)


class ApiError(Exception):
    """The server refused a request. ``status`` is the HTTP code, ``detail`` its message."""

    def __init__(self, status: int, detail: str, code: str = "") -> None:
        super().__init__(f"{status} {code}: {detail}" if code else f"{status}: {detail}")
        self.status = status
        self.detail = detail
        self.code = code


class TeachRepeatClient:
    """One robot's (or the admin's) connection to a teachrepeat server.

    Keeps one HTTP connection alive. ``retries`` > 0 retries connection failures with
    exponential backoff (``backoff_s``, doubling), for a server that restarts.
    """

    def __init__(
        self,
        base_url: str,
        token: str,
        *,
        timeout_s: float = 10.0,
        retries: int = 0,
        backoff_s: float = 0.2,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        self._http = httpx.Client(
            base_url=base_url.rstrip("/"),
            headers={"Authorization": f"Bearer {token}"},
            timeout=timeout_s,
            transport=transport,
        )
        self.retries = retries
        self.backoff_s = backoff_s

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> TeachRepeatClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- plumbing -------------------------------------------------------------------------

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        delay = self.backoff_s
        for attempt in range(self.retries + 1):
            try:
                response = self._http.request(method, path, **kwargs)
                break
            except httpx.TransportError:
                if attempt == self.retries:
                    raise
                time.sleep(delay)
                delay *= 2
        if response.status_code >= 400:
            try:
                body = response.json()
                raise ApiError(response.status_code, body.get("detail", ""), body.get("code", ""))
            except ValueError:
                raise ApiError(response.status_code, response.text) from None
        return response

    def _call(self, model: type[M], method: str, path: str, **kwargs: Any) -> M:
        return model.model_validate_json(self._request(method, path, **kwargs).content)

    def _list(self, item: type[M], path: str) -> list[M]:
        return TypeAdapter(list[item]).validate_json(self._request("GET", path).content)  # type: ignore[valid-type]

    # --- admin ----------------------------------------------------------------------------

    def whoami(self) -> schemas.WhoAmI:
        return self._call(schemas.WhoAmI, "GET", "/whoami")

    def register_robot(self, name: str) -> schemas.RobotRegistered:
        body = schemas.RobotCreate(name=name).model_dump()
        return self._call(schemas.RobotRegistered, "POST", "/robots", json=body)

    # --- tours ----------------------------------------------------------------------------

    def create_tour(self, name: str) -> schemas.TourSummary:
        body = schemas.TourCreate(name=name).model_dump()
        return self._call(schemas.TourSummary, "POST", "/tours", json=body)

    def tours(self) -> list[schemas.TourSummary]:
        return self._list(schemas.TourSummary, "/tours")

    def tour(self, tour_id: int) -> schemas.TourGraphPublic:
        return self._call(schemas.TourGraphPublic, "GET", f"/tours/{tour_id}")

    def tour_named(self, name: str, *, create: bool = False) -> schemas.TourSummary:
        """The tour called ``name``; created when missing and ``create`` is set."""
        for tour in self.tours():
            if tour.name == name:
                return tour
        if not create:
            raise ApiError(404, f"no tour named {name!r}", "not_found")
        return self.create_tour(name)

    def image(self, image_id: int) -> bytes:
        return self._request("GET", f"/images/{image_id}").content

    # --- one robot ------------------------------------------------------------------------

    def state(self, robot: str) -> schemas.RobotState:
        return self._call(schemas.RobotState, "GET", f"/robots/{robot}/state")

    def start_teaching(self, robot: str, tour_id: int) -> schemas.TeachingState:
        body = schemas.TeachStart(tour=tour_id).model_dump()
        return self._call(schemas.TeachingState, "POST", f"/robots/{robot}/teach/start", json=body)

    def mark_location(self, robot: str, name: str) -> schemas.MarkResult:
        body = schemas.LocationMark(name=name).model_dump()
        return self._call(schemas.MarkResult, "POST", f"/robots/{robot}/teach/locations", json=body)

    def upload_frame(
        self,
        robot: str,
        jpeg: bytes,
        *,
        timestamp: float,
        v: float = 0.0,
        w: float = 0.0,
        depth: Sequence[float] | None = None,
        timeout: float | None = None,
    ) -> schemas.FrameResult | schemas.NavigationFrameResult:
        """Send a frame: appended while teaching, answered with a motion command while
        navigating (a :class:`~server.schemas.NavigationFrameResult`). ``timeout`` (s)
        overrides the client's for this request."""
        params: dict[str, Any] = _meta(timestamp, v, w)
        if depth is not None:
            params["depth"] = [round(float(r), 3) for r in depth]
        response = self._request(
            "POST",
            f"/robots/{robot}/frames",
            params=params,
            content=jpeg,
            headers={"Content-Type": "image/jpeg"},
            **({} if timeout is None else {"timeout": timeout}),
        )
        return _FRAME_RESULT.validate_json(response.content)

    def goto(
        self, robot: str, location: str, *, tour: int | None = None, timeout_s: float = 120.0
    ) -> schemas.TaskPublic:
        """Start navigating to ``location``. The first goto on a freshly taught tour may wait
        while the server prepares it (features, weights), hence the long ``timeout_s``."""
        body = schemas.GotoRequest(location=location, tour=tour).model_dump()
        return self._call(
            schemas.TaskPublic, "POST", f"/robots/{robot}/goto", json=body, timeout=timeout_s
        )

    def stop(self, robot: str) -> schemas.TaskPublic:
        return self._call(schemas.TaskPublic, "POST", f"/robots/{robot}/stop")

    def upload_spin_image(
        self, robot: str, jpeg: bytes, *, timestamp: float, v: float = 0.0, w: float = 0.0
    ) -> schemas.ImageStored:
        return self._call(
            schemas.ImageStored,
            "POST",
            f"/robots/{robot}/teach/spin",
            params=_meta(timestamp, v, w),
            content=jpeg,
            headers={"Content-Type": "image/jpeg"},
        )

    def finish_teaching(self, robot: str) -> schemas.TeachingEnded:
        return self._call(schemas.TeachingEnded, "POST", f"/robots/{robot}/teach/finish")

    def abort_teaching(self, robot: str) -> schemas.TeachingEnded:
        return self._call(schemas.TeachingEnded, "POST", f"/robots/{robot}/teach/abort")


def _meta(timestamp: float, v: float, w: float) -> dict[str, Any]:
    return schemas.FrameMeta(timestamp=timestamp, v=v, w=w).model_dump(exclude_none=True)


_FRAME_RESULT: TypeAdapter[schemas.FrameResult | schemas.NavigationFrameResult] = TypeAdapter(
    schemas.AnyFrameResult
)
