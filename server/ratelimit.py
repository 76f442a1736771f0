"""Rate limits as token buckets: per bearer token, per client address, and for failed
authentications per address. Pure: the caller passes the time; nothing here does I/O.

A bucket holds up to ``burst`` tokens and refills at ``rate`` per second; a request takes one.
An empty bucket answers how long to wait (the ``Retry-After`` of a 429).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass


@dataclass(frozen=True)
class RateLimits:
    """Defaults fit a household: a robot sends 10 frames/s plus a few control calls; a
    browser or script a few calls/s. Every field is a deployment setting (server.config)."""

    token_per_s: float = 200.0
    """Sustained requests per second one bearer token may make. A robot streaming frames
    sends 10; uploading a recorded tour as fast as loopback allows, about 400 (it then waits
    as told by Retry-After: the robot client does)."""
    token_burst: float = 400.0
    """Requests one token may make at once after a quiet spell."""
    address_per_s: float = 1000.0
    """Sustained requests per second from one client address (all tokens together)."""
    address_burst: float = 2000.0
    failed_auth_per_s: float = 0.2
    """Failed authentications (401) one address is forgiven per second, in the long run."""
    failed_auth_burst: float = 10.0
    """Failed authentications one address may make before every request it makes waits."""
    max_keys: int = 100_000
    """Buckets remembered per kind; the least recently used go first (bounded memory)."""


class Buckets:
    """Token buckets keyed by a string, least recently used forgotten beyond ``max_keys``."""

    def __init__(self, rate: float, burst: float, max_keys: int) -> None:
        self.rate = rate
        self.burst = burst
        self.max_keys = max_keys
        self._levels: OrderedDict[str, tuple[float, float]] = OrderedDict()  # key -> level, at

    def level(self, key: str, now: float) -> float:
        level, at = self._levels.get(key, (self.burst, now))
        return min(self.burst, level + (now - at) * self.rate)

    def take(self, key: str, now: float, amount: float = 1.0) -> float:
        """Take ``amount`` from ``key``'s bucket when it holds that much; returns 0.0 then,
        else the seconds until it will (and takes nothing)."""
        level = self.level(key, now)
        if level < amount:
            if key in self._levels:
                self._levels.move_to_end(key)  # in use: not the first to be forgotten
            return (amount - level) / self.rate
        self._set(key, level - amount, now)
        return 0.0

    def wait(self, key: str, now: float) -> float:
        """Seconds until ``key``'s bucket holds one token (0.0 when it does), taking none."""
        level = self.level(key, now)
        return 0.0 if level >= 1.0 else (1.0 - level) / self.rate

    def charge(self, key: str, now: float) -> None:
        """Take one token, even below zero (failures are counted however many there are)."""
        self._set(key, max(self.level(key, now) - 1.0, -self.burst), now)

    def _set(self, key: str, level: float, now: float) -> None:
        self._levels[key] = (level, now)
        self._levels.move_to_end(key)
        while len(self._levels) > self.max_keys:
            self._levels.popitem(last=False)


class RateLimiter:
    """The three limits together; thread-safe."""

    def __init__(self, limits: RateLimits) -> None:
        self.limits = limits
        self._tokens = Buckets(limits.token_per_s, limits.token_burst, limits.max_keys)
        self._addresses = Buckets(limits.address_per_s, limits.address_burst, limits.max_keys)
        self._failures = Buckets(
            limits.failed_auth_per_s, limits.failed_auth_burst, limits.max_keys
        )
        self._lock = threading.Lock()

    def admit(self, address: str, token: str | None, now: float) -> tuple[float, str]:
        """``(0.0, "")`` when the request may go on, else ``(seconds to wait, why)``."""
        with self._lock:
            wait = self._failures.wait(address, now)
            if wait > 0:
                return wait, "too many failed authentications from this address"
            wait = self._addresses.take(address, now)
            if wait > 0:
                return wait, "too many requests from this address"
            if token is not None:
                wait = self._tokens.take(token, now)
                if wait > 0:
                    return wait, "too many requests with this token"
        return 0.0, ""

    def failed(self, address: str, now: float) -> None:
        """The request from ``address`` failed to authenticate (401)."""
        with self._lock:
            self._failures.charge(address, now)
