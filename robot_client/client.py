"""The HTTP client a robot (or a script) uses, typed with the server's wire schemas."""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeVar

import httpx
from pydantic import BaseModel, TypeAdapter

from robot_client import pinning
from robot_client.pinning import UntrustedServerError
from server import schemas

M = TypeVar("M", bound=BaseModel)


class ApiError(Exception):
    """The server refused a request. ``status`` is the HTTP code, ``detail`` its message."""

    def __init__(self, status: int, detail: str, code: str = "") -> None:
        super().__init__(f"{status} {code}: {detail}" if code else f"{status}: {detail}")
        self.status = status
        self.detail = detail
        self.code = code


GATEWAY_ERRORS = frozenset({502, 504})
"""Statuses a load balancer answers for a server process that died or did not answer."""


class TeachRepeatClient:
    """One robot's (or the admin's) connection to a teachrepeat server.

    Keeps one HTTP connection alive. ``retries`` > 0 retries connection failures and a
    gateway's 502 / 504 (HAProxy's answer when the server process behind it died with the
    request, ``serve --workers``; the server itself never answers them) with exponential
    backoff (``backoff_s``, doubling), for a server that restarts. A request
    refused as too many (429) is sent again after the ``Retry-After`` the server gives, while
    the waits add up to at most ``max_wait_s``; then the 429 is raised as :class:`ApiError`.

    Over ``https://``, ``ca_cert`` (a copy of the server's ``cert.pem``) and ``fingerprint``
    (its SHA-256, hex with or without colons) pin the server's certificate
    (:func:`robot_client.pinning.ssl_context`): a server with another certificate fails the
    TLS handshake, before the token is sent, with :class:`UntrustedServerError` (never
    retried). Without either, the system's certificate authorities decide. ``transport``
    (tests) replaces the network, and with it TLS.
    """

    def __init__(
        self,
        base_url: str,
        token: str,
        *,
        timeout_s: float = 10.0,
        retries: int = 0,
        backoff_s: float = 0.2,
        max_wait_s: float = 10.0,
        ca_cert: Path | None = None,
        fingerprint: str | None = None,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        context = pinning.ssl_context(ca_cert=ca_cert, fingerprint=fingerprint)
        if context is not None and not base_url.startswith("https://"):
            raise ValueError(
                f"{base_url}: a pinned certificate (--ca-cert, --fingerprint) needs an "
                "https:// server URL; over http:// the token would travel in clear"
            )
        self._http = httpx.Client(
            base_url=base_url.rstrip("/"),
            headers={"Authorization": f"Bearer {token}"},
            timeout=timeout_s,
            verify=True if context is None else context,
            transport=transport,
        )
        self.ca_cert = ca_cert
        self.retries = retries
        self.max_wait_s = max_wait_s
        self.backoff_s = backoff_s

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> TeachRepeatClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- plumbing -------------------------------------------------------------------------

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        waited = 0.0
        while True:
            response = self._send(method, path, **kwargs)
            if response.status_code != 429:
                break
            wait = _retry_after_s(response)
            if wait is None or waited + wait > self.max_wait_s:
                break
            time.sleep(wait)  # rate-limited: wait as told, then send it again
            waited += wait
        if response.status_code >= 400:
            try:
                body = response.json()
                raise ApiError(response.status_code, body.get("detail", ""), body.get("code", ""))
            except ValueError:
                raise ApiError(response.status_code, response.text) from None
        return response

    def _send(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        delay = self.backoff_s
        for attempt in range(self.retries + 1):
            try:
                response = self._http.request(method, path, **kwargs)
                if response.status_code not in GATEWAY_ERRORS or attempt == self.retries:
                    return response
            except httpx.TransportError as exc:
                refused = pinning.explain(exc, ca_cert=self.ca_cert)
                if refused is not None:
                    raise UntrustedServerError(refused) from exc
                if attempt == self.retries:
                    raise
            time.sleep(delay)
            delay *= 2
        raise AssertionError("unreachable")  # pragma: no cover

    def _call(self, model: type[M], method: str, path: str, **kwargs: Any) -> M:
        return model.model_validate_json(self._request(method, path, **kwargs).content)

    def _list(self, item: type[M], path: str) -> list[M]:
        return TypeAdapter(list[item]).validate_json(self._request("GET", path).content)  # type: ignore[valid-type]

    def health(self) -> dict[str, Any]:
        """The server's ``/health`` answer (needs no token): ``{"status": "ok", ...}``."""
        body: dict[str, Any] = self._request("GET", "/health").json()
        return body

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

    def start_teaching(
        self, robot: str, tour_id: int, *, record: bool | None = None
    ) -> schemas.TeachingState:
        """Begin teaching ``tour_id``; ``record``: record it (``None``: the server decides)."""
        body = schemas.TeachStart(tour=tour_id, record=record).model_dump(exclude_none=True)
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
        pose: Sequence[float] | None = None,
        stream: bool = False,
    ) -> schemas.FrameResult | schemas.NavigationFrameResult | schemas.IdleFrameResult:
        """Send a frame: appended while teaching, answered with a motion command while
        navigating (a :class:`~server.schemas.NavigationFrameResult`) and in every other
        mode. ``timeout`` (s) overrides the client's for this request; ``pose``
        ``(x, y, theta)`` (m, m, rad) is where the camera was, kept with a taught image;
        ``stream``: the robot streams all the time and the server decides what to keep (the
        robot agent, :class:`~server.schemas.FrameMeta`)."""
        params: dict[str, Any] = _meta(timestamp, v, w, pose)
        if depth is not None:
            params["depth"] = [wire_range(r) for r in depth]
        if stream:
            params["stream"] = "true"
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
        self,
        robot: str,
        location: str,
        *,
        tour: int | None = None,
        record: bool | None = None,
        timeout_s: float = 120.0,
    ) -> schemas.TaskPublic:
        """Start navigating to ``location``; ``record``: record the task (``None``: the server
        decides). The first goto on a freshly taught tour may wait while the server prepares
        it (features, weights), hence the long ``timeout_s``."""
        body = schemas.GotoRequest(location=location, tour=tour, record=record).model_dump(
            exclude_none=True
        )
        return self._call(
            schemas.TaskPublic, "POST", f"/robots/{robot}/goto", json=body, timeout=timeout_s
        )

    def stop(self, robot: str) -> schemas.TaskPublic:
        return self._call(schemas.TaskPublic, "POST", f"/robots/{robot}/stop")

    def teleop(self, robot: str, v: float, w: float, *, ttl_s: float = 0.5) -> schemas.TeleopState:
        """Drive the robot by hand at ``v`` m/s and ``w`` rad/s for ``ttl_s`` seconds (send it
        again to keep driving; ``v = w = 0`` stops)."""
        body = schemas.TeleopCommand(v=v, w=w, ttl_s=ttl_s).model_dump()
        return self._call(schemas.TeleopState, "POST", f"/robots/{robot}/teleop", json=body)

    def halt(self, robot: str) -> schemas.RobotState:
        """Stop whatever the robot does (driving by hand, a spin, a navigation task)."""
        return self._call(schemas.RobotState, "POST", f"/robots/{robot}/halt")

    def learned(self, tour: int) -> list[schemas.LearnedChange]:
        """The tour's learned changes (docs/learning.md)."""
        return self._list(schemas.LearnedChange, f"/tours/{tour}/learned")

    def unlearn(self, tour: int, change: int) -> None:
        """Remove one learned change of the tour."""
        self._request("DELETE", f"/tours/{tour}/learned/{change}")

    def questions(self, robot: str) -> list[schemas.QuestionPublic]:
        """The robot's open questions (docs/learning.md), oldest first."""
        return self._list(schemas.QuestionPublic, f"/robots/{robot}/questions")

    def answer(self, robot: str, question: int, answer: str) -> schemas.QuestionPublic:
        """Answer one of the robot's questions 'yes' or 'no'."""
        body = schemas.QuestionAnswer.model_validate({"answer": answer}).model_dump()
        return self._call(
            schemas.QuestionPublic, "POST", f"/robots/{robot}/questions/{question}", json=body
        )

    def recordings(self, robot: str) -> list[schemas.RecordingPublic]:
        """The robot's recordings, newest first."""
        return self._list(schemas.RecordingPublic, f"/robots/{robot}/recordings")

    def recording(self, robot: str, name: str) -> bytes:
        """The MCAP bytes of the robot's recording ``name``."""
        return self._request("GET", f"/robots/{robot}/recordings/{name}").content

    def upload_spin_image(
        self,
        robot: str,
        jpeg: bytes,
        *,
        timestamp: float,
        v: float = 0.0,
        w: float = 0.0,
        pose: Sequence[float] | None = None,
        depth: Sequence[float] | None = None,
    ) -> schemas.ImageStored:
        """A spin image of the current place, with the robot's odometry and, when it has a
        depth sensor, its depth profile (metres, left to right)."""
        params = _meta(timestamp, v, w, pose)
        if depth is not None:
            params["depth"] = [wire_range(r) for r in depth]
        return self._call(
            schemas.ImageStored,
            "POST",
            f"/robots/{robot}/teach/spin",
            params=params,
            content=jpeg,
            headers={"Content-Type": "image/jpeg"},
        )

    def finish_teaching(self, robot: str) -> schemas.TeachingEnded:
        return self._call(schemas.TeachingEnded, "POST", f"/robots/{robot}/teach/finish")

    def abort_teaching(self, robot: str) -> schemas.TeachingEnded:
        return self._call(schemas.TeachingEnded, "POST", f"/robots/{robot}/teach/abort")


def _meta(
    timestamp: float, v: float, w: float, pose: Sequence[float] | None = None
) -> dict[str, Any]:
    return schemas.FrameMeta(
        timestamp=timestamp, v=v, w=w, pose=None if pose is None else [float(x) for x in pose]
    ).model_dump(exclude_none=True)


def wire_range(r: float) -> float:
    """One depth range as the server takes it: a ray that saw nothing (inf, NaN) or saw
    beyond ``schemas.MAX_DEPTH_M`` is sent as that maximum; millimetres are enough."""
    r = float(r)
    if not r <= schemas.MAX_DEPTH_M:  # inf, NaN or too far
        return schemas.MAX_DEPTH_M
    return round(max(r, 0.0), 3)


_FRAME_RESULT: TypeAdapter[
    schemas.FrameResult | schemas.NavigationFrameResult | schemas.IdleFrameResult
] = TypeAdapter(schemas.AnyFrameResult)


def _retry_after_s(response: httpx.Response) -> float | None:
    """The seconds a 429 answer says to wait (``Retry-After``), or ``None`` without one."""
    try:
        return max(0.0, float(response.headers["retry-after"]))
    except (KeyError, ValueError):
        return None
