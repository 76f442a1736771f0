"""The path tracker's word in the belief (:func:`path_likelihood`): a likelihood over the fine
states that favours the tracked edge's images near the tracked position, against a naive
per-state reference."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from navigation_testkit import path_estimate

from server.navigation.pathtrack import PathEstimate, path_likelihood


def estimate(along_m: float, sigma_along: float, *, locked: bool = True) -> PathEstimate:
    """A path estimate on edge 0 at ``along_m`` metres (the rest does not matter here)."""
    return path_estimate(along=along_m, sigma_along=sigma_along, locked=locked)


def naive(est: PathEstimate, first: int, along: np.ndarray, n_fine: int, ratio: float) -> list:
    """One state at a time: the tracked edge's images by a Gaussian in metres from the tracked
    position (sd at least 0.3 m), between 1 / ratio and 1; every other state 1 / ratio."""
    sigma = max(est.sigma_along, 0.3)
    out = []
    for s in range(n_fine):
        if first <= s < first + len(along):
            near = math.exp(-0.5 * ((along[s - first] - est.along_m) / sigma) ** 2)
            out.append(1.0 / ratio + (1.0 - 1.0 / ratio) * near)
        else:
            out.append(1.0 / ratio)
    return out


@given(
    n_images=st.integers(1, 40),
    before=st.integers(0, 30),
    after=st.integers(0, 30),
    along_m=st.floats(-1.0, 6.0),
    sigma=st.floats(0.0, 2.0),
    ratio=st.floats(1.01, 50.0),
)
def test_it_matches_the_naive_reference_state_by_state(
    n_images: int, before: int, after: int, along_m: float, sigma: float, ratio: float
) -> None:
    along = np.linspace(0.0, 5.0, n_images)
    n_fine = before + n_images + after
    est = estimate(along_m, sigma)
    out = path_likelihood(est, before, along, n_fine, ratio)
    assert out is not None and out.shape == (n_fine,)
    np.testing.assert_allclose(out, naive(est, before, along, n_fine, ratio), rtol=1e-12)
    # never more than ratio times apart, the tracked position's image the likeliest
    assert out.max() / out.min() <= ratio * (1 + 1e-12)
    nearest = before + int(np.argmin(np.abs(along - along_m)))
    assert out[nearest] == out.max()


def test_a_tracker_not_locked_or_a_ratio_of_one_has_no_word() -> None:
    along = np.linspace(0.0, 2.0, 5)
    assert path_likelihood(None, 0, along, 8, 4.0) is None
    assert path_likelihood(estimate(1.0, 0.1, locked=False), 0, along, 8, 4.0) is None
    assert path_likelihood(estimate(1.0, 0.1), 0, along, 8, 1.0) is None


def test_the_tracked_image_weighs_ratio_times_a_state_off_the_edge() -> None:
    along = np.arange(10) * 0.5
    out = path_likelihood(estimate(2.0, 0.05), 3, along, 20, 4.0)
    assert out is not None
    assert out[3 + 4] == 1.0  # along 2.0 m: the tracked position
    assert out[0] == out[19] == 0.25  # a place, another edge's image
    assert out[3] < out[3 + 2] < out[3 + 4]  # rising toward the tracked position
