"""Households, their logins, and who a bearer token belongs to.

A household owns its robots and tours (and through the tours every image, place, edge and
task). Three kinds of caller exist: the admin (administration only: households, robots,
audit), a robot (its own routes, its household's tours), and a household login (everything of
its household, for the dashboard and scripts). Tokens and logins are stored as SHA-256 hashes;
passwords as argon2id hashes.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from server import schemas
from server.errors import Conflict, IntegrityViolation, TooMany, Unauthorized
from server.security import hash_password, hash_token, new_token, verify_password
from server.storage.repo import Repo

TOKEN_CACHE_S = 60.0
"""Seconds a robot token or login found in the database is remembered. Rotation, revocation
and logout through the API forget it at once; a row removed by hand stops authenticating
within this time."""


@dataclass(frozen=True)
class Principal:
    """Who is calling: the admin, one registered robot, or one household's login."""

    kind: Literal["admin", "robot", "household"]
    robot: str | None = None
    household: int | None = None
    household_name: str | None = None

    @property
    def actor(self) -> str:
        """How the audit log names the caller (never with a secret)."""
        if self.kind == "robot":
            return f"robot:{self.robot}"
        if self.kind == "household":
            return f"household:{self.household_name}"
        return "admin"


ADMIN = Principal("admin")


class Identities:
    """Bearer token -> :class:`Principal`, for robot tokens and household logins.

    ``cached`` answers from memory (safe on the event loop); ``lookup`` reads the database and
    remembers what it finds (never unknown tokens: no memory for a caller trying random ones).
    """

    def __init__(
        self,
        repo: Repo,
        *,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        max_entries: int = 10_000,
    ) -> None:
        self.repo = repo
        self.clock = clock
        self.wall = wall
        self.max_entries = max_entries
        # token hash -> (principal, found at (clock), expires at (wall) or None)
        self._cache: OrderedDict[str, tuple[Principal, float, float | None]] = OrderedDict()
        self._lock = threading.Lock()

    def cached(self, token_hash: str) -> Principal | None:
        with self._lock:
            hit = self._cache.get(token_hash)
            if hit is None:
                return None
            principal, found_at, expires_at = hit
            stale = self.clock() - found_at > TOKEN_CACHE_S
            if stale or (expires_at is not None and self.wall() >= expires_at):
                del self._cache[token_hash]
                return None
            return principal

    def lookup(self, token_hash: str) -> Principal | None:
        expires_at: float | None = None
        robot = self.repo.robot_by_token_hash(token_hash)
        if robot is not None:
            principal = Principal("robot", robot[0], robot[1], robot[2])
        else:
            login = self.repo.login(token_hash)
            if login is None or self.wall() >= login[2]:
                return None
            principal = Principal("household", None, login[0], login[1])
            expires_at = login[2]
        with self._lock:
            self._cache[token_hash] = (principal, self.clock(), expires_at)
            while len(self._cache) > self.max_entries:
                self._cache.popitem(last=False)
        return principal

    def forget(self, token_hash: str) -> None:
        with self._lock:
            self._cache.pop(token_hash, None)

    def forget_robot(self, robot: str) -> None:
        """Forget every cached token of ``robot`` (after rotation or revocation)."""
        with self._lock:
            for key in [k for k, v in self._cache.items() if v[0].robot == robot]:
                del self._cache[key]


@dataclass(frozen=True)
class LoginParams:
    """How long a login lasts and how failed logins slow down."""

    lifetime_s: float = 12 * 3600.0
    """A login token is refused this long after it was issued, s."""
    free_failures: int = 3
    """Failed logins for one household name before each further try must wait."""
    max_wait_s: float = 300.0
    """Longest wait after repeated failures, s (the wait doubles from 1 s up to this)."""


class HouseholdService:
    def __init__(
        self,
        repo: Repo,
        identities: Identities,
        params: LoginParams | None = None,
        *,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.repo = repo
        self.identities = identities
        self.params = params or LoginParams()
        self.wall = wall
        self._failures: OrderedDict[str, tuple[int, float]] = OrderedDict()  # name -> n, until
        self._failures_lock = threading.Lock()

    def create(self, body: schemas.HouseholdCreate) -> schemas.HouseholdPublic:
        password_hash = None if body.password is None else hash_password(body.password)
        try:
            with self.repo.transaction():
                if self.repo.household_by_name(body.name) is not None:
                    raise Conflict(f"a household named {body.name!r} exists already")
                row = self.repo.add_household(body.name, password_hash)
        except IntegrityViolation as exc:  # pragma: no cover - a concurrent create
            raise Conflict(f"a household named {body.name!r} exists already") from exc
        return schemas.HouseholdPublic(
            id=row.id,
            name=row.name,
            created_at=row.created_at,
            has_login=row.has_login,
            robots=0,
            tours=0,
        )

    def list(self) -> list[schemas.HouseholdPublic]:
        with self.repo.snapshot():
            rows = self.repo.households()
            robots = self.repo.robots()
            tours = self.repo.tours()
        return [
            schemas.HouseholdPublic(
                id=h.id,
                name=h.name,
                created_at=h.created_at,
                has_login=h.has_login,
                robots=sum(r.household_id == h.id for r in robots),
                tours=sum(t.household_id == h.id for t, *_ in tours),
            )
            for h in rows
        ]

    def set_password(self, household_id: int, body: schemas.PasswordSet) -> None:
        password_hash = hash_password(body.password)
        with self.repo.transaction():
            self.repo.household(household_id)  # 404 when unknown
            self.repo.set_password_hash(household_id, password_hash)

    def login(self, body: schemas.LoginRequest) -> schemas.LoginResult:
        """A login token for the household, or 401 (the same answer for an unknown name and a
        wrong password), or 429 while repeated failures make this name wait."""
        self._check_wait(body.household)
        row = self.repo.household_by_name(body.household)
        ok = verify_password(body.password, None if row is None else row.password_hash)
        if row is None or not ok:
            self._failed(body.household)
            raise Unauthorized("wrong household or password")
        with self._failures_lock:
            self._failures.pop(body.household, None)
        token = new_token()
        expires_at = self.wall() + self.params.lifetime_s
        with self.repo.transaction():
            self.repo.add_login(hash_token(token), row.id, expires_at)
        return schemas.LoginResult(token=token, household=row.name, expires_at=expires_at)

    def logout(self, token: str) -> None:
        token_hash = hash_token(token)
        with self.repo.transaction():
            self.repo.end_login(token_hash)
        self.identities.forget(token_hash)

    def _check_wait(self, name: str) -> None:
        with self._failures_lock:
            hit = self._failures.get(name)
        if hit is not None and self.wall() < hit[1]:
            wait = hit[1] - self.wall()
            raise TooMany(f"too many failed logins for {name!r}; try again in {wait:.0f} s", wait)

    def _failed(self, name: str) -> None:
        p = self.params
        with self._failures_lock:
            count = self._failures.pop(name, (0, 0.0))[0] + 1
            wait = (
                0.0
                if count < p.free_failures
                else min(2.0 ** (count - p.free_failures), p.max_wait_s)
            )
            self._failures[name] = (count, self.wall() + wait)
            while len(self._failures) > 10_000:
                self._failures.popitem(last=False)
