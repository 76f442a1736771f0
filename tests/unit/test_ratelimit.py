"""Token buckets: properties against their definition, and the three limits together."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from server.ratelimit import Buckets, RateLimiter, RateLimits

gaps = st.lists(st.floats(min_value=0.0, max_value=0.5), min_size=1, max_size=200)


@settings(max_examples=200, deadline=None)
@given(gaps, st.floats(1.0, 50.0), st.floats(1.0, 20.0))
def test_no_window_admits_more_than_burst_plus_rate_times_its_length(
    dts: list[float], rate: float, burst: float
) -> None:
    buckets = Buckets(rate, burst, max_keys=10)
    t, admitted = 0.0, []
    for dt in dts:
        t += dt
        if buckets.take("k", t) == 0.0:
            admitted.append(t)
    # the naive check: every window [admitted[i], admitted[j]] holds at most burst + rate * len
    for i in range(len(admitted)):
        for j in range(i, len(admitted)):
            assert j - i + 1 <= burst + rate * (admitted[j] - admitted[i]) + 1e-6


@settings(max_examples=200, deadline=None)
@given(gaps, st.floats(1.0, 50.0), st.floats(1.0, 20.0))
def test_waiting_the_answered_time_is_enough(dts: list[float], rate: float, burst: float) -> None:
    buckets = Buckets(rate, burst, max_keys=10)
    t = 0.0
    for dt in dts:
        t += dt
        wait = buckets.take("k", t)
        if wait > 0:
            assert buckets.take("k", t + wait + 1e-9) == 0.0
            t += wait + 1e-9


def test_a_quiet_key_starts_full_and_keys_are_independent() -> None:
    buckets = Buckets(rate=1.0, burst=3.0, max_keys=10)
    assert [buckets.take("a", 0.0) for _ in range(4)] == [0.0, 0.0, 0.0, 1.0]
    assert buckets.take("b", 0.0) == 0.0


def test_memory_is_bounded_least_recently_used_first() -> None:
    buckets = Buckets(rate=1.0, burst=1.0, max_keys=2)
    buckets.take("a", 0.0)
    buckets.take("b", 0.0)
    buckets.take("a", 0.0)  # refused, but a is used
    buckets.take("c", 0.0)
    assert buckets.take("a", 0.0) > 0  # a was remembered
    assert buckets.take("b", 0.0) == 0.0  # b was forgotten: full again


def test_failed_authentications_make_every_request_from_the_address_wait() -> None:
    limiter = RateLimiter(RateLimits(failed_auth_burst=3, failed_auth_per_s=0.5))
    for _ in range(3):
        assert limiter.admit("10.0.0.2", "guess", 0.0) == (0.0, "")
        limiter.failed("10.0.0.2", 0.0)
    wait, why = limiter.admit("10.0.0.2", "the-right-token", 0.0)
    assert wait == 2.0 and "failed authentications" in why
    assert limiter.admit("10.0.0.3", None, 0.0) == (0.0, "")  # another address is not held up
    assert limiter.admit("10.0.0.2", None, 2.0) == (0.0, "")  # forgiven in time


def test_one_token_is_limited_wherever_it_comes_from() -> None:
    limiter = RateLimiter(RateLimits(token_per_s=1.0, token_burst=2.0))
    assert limiter.admit("10.0.0.2", "t", 0.0)[0] == 0.0
    assert limiter.admit("10.0.0.3", "t", 0.0)[0] == 0.0
    wait, why = limiter.admit("10.0.0.4", "t", 0.0)
    assert wait == 1.0 and "token" in why
