"""Named domain errors. The API maps each to its HTTP status in one exception handler.

Every message says what was wrong and what to do about it.
"""

from __future__ import annotations


class DomainError(Exception):
    """Base of every error the service layer raises on purpose."""

    status = 400
    code = "bad_request"

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class NotFound(DomainError):
    status = 404
    code = "not_found"


class Conflict(DomainError):
    status = 409
    code = "conflict"


class Gone(DomainError):
    """It existed but is over (a question past its expiry)."""

    status = 410
    code = "gone"


class Invalid(DomainError):
    status = 422
    code = "invalid"


class TooLarge(DomainError):
    status = 413
    code = "too_large"


class UnsupportedMedia(DomainError):
    status = 415
    code = "unsupported_media_type"


class Unauthorized(DomainError):
    status = 401
    code = "unauthorized"


class Forbidden(DomainError):
    status = 403
    code = "forbidden"


class Unavailable(DomainError):
    """The server cannot do it right now (disk full, read-only database)."""

    status = 503
    code = "unavailable"


class TooMany(DomainError):
    """Too many requests (or failed logins): retry after ``retry_after_s`` seconds."""

    status = 429
    code = "too_many_requests"

    def __init__(self, message: str, retry_after_s: float) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


class IntegrityViolation(Exception):
    """The database refused a write that breaks one of its constraints (a unique name taken,
    a reference to nothing). Raised by storage on SQLite and PostgreSQL alike; a service that
    expects one (a concurrent create) turns it into a :class:`Conflict`. Not a
    :class:`DomainError`: one nobody expected is a server error (500), as before."""
