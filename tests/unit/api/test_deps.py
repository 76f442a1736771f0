"""server.api.deps: an upload's query string read by hand (read_query, query_openapi) against
FastAPI's own ``Query()`` model parameter, the naive reference it stands in for."""

from __future__ import annotations

from typing import Annotated, Any

import pytest
from fastapi import FastAPI, Query, Request
from fastapi.testclient import TestClient

from server import schemas
from server.api.deps import query_openapi, read_query

QUERIES = [
    "timestamp=1.5",
    "timestamp=1.5&v=0.3&w=-0.2",
    "timestamp=2&depth=1.2&depth=0.9&depth=1000",
    "timestamp=2&pose=1&pose=2&pose=0.5",
    "timestamp=2&timestamp=3",
    "timestamp=2&depth=4",
    "",
    "timestamp=-1",
    "timestamp=abc&v=9",
    "timestamp=1&foo=2",
    "timestamp=1&depth=1&depth=x",
    "timestamp=1&pose=1",
    "timestamp=1&depth=inf",
    "timestamp=1&v=nan",
]


def _apps() -> tuple[TestClient, TestClient]:
    """The reference (FastAPI's ``Query()`` model) and ours, each answering the parsed model or
    FastAPI's 422 errors."""
    reference = FastAPI()

    @reference.post("/r")
    def by_fastapi(meta: Annotated[schemas.FrameMeta, Query()]) -> dict[str, Any]:
        return meta.model_dump()

    ours = FastAPI()

    @ours.post("/r", openapi_extra={"parameters": query_openapi(schemas.FrameMeta)})
    def by_hand(request: Request) -> dict[str, Any]:
        return read_query(schemas.FrameMeta, request).model_dump()

    return TestClient(reference), TestClient(ours)


@pytest.mark.parametrize("query", QUERIES)
def test_read_query_answers_as_a_query_model(query: str) -> None:
    reference, ours = _apps()
    expected = reference.post(f"/r?{query}")
    got = ours.post(f"/r?{query}")
    assert got.status_code == expected.status_code, (query, got.text, expected.text)
    if expected.status_code == 200:
        assert got.json() == expected.json()
    else:
        strip = [{k: e[k] for k in ("type", "loc", "msg")} for e in expected.json()["detail"]]
        assert [{k: e[k] for k in ("type", "loc", "msg")} for e in got.json()["detail"]] == strip


def test_query_openapi_documents_what_a_query_model_does() -> None:
    reference, ours = _apps()
    expected = reference.get("/openapi.json").json()["paths"]["/r"]["post"]["parameters"]
    assert ours.get("/openapi.json").json()["paths"]["/r"]["post"]["parameters"] == expected
    assert {p["name"] for p in expected} == set(schemas.FrameMeta.model_fields)
