"""Experiences in the index (docs/learning.md): another appearance of a taught image answers for
it; without experiences the index answers exactly as before."""

from __future__ import annotations

import numpy as np
import pytest
from vision_testkit import index_of, scene

from server.vision import extract


def _dark(img: np.ndarray) -> np.ndarray:
    """The same place at night: darker, bluish, flatter contrast."""
    out = img.astype(np.float64) * np.array([0.35, 0.3, 0.5]) + 10
    return np.clip(out, 0, 255).astype(np.uint8)


def test_an_experience_answers_for_its_taught_image_and_results_keep_their_shape() -> None:
    images = [scene(s) for s in range(9)]
    states = [s // 3 for s in range(9)]
    idx, feats = index_of(images, states)
    night = extract(_dark(images[4]))
    before = idx.query(night, n_states=3)
    idx.add_experiences([night], [4])
    assert (idx.n_images, idx.n_taught) == (10, 9)
    after = idx.query(night, n_states=3)
    assert after.image.shape == (9,) and after.state.shape == (3,)
    assert int(np.argmax(after.image)) == 4 and after.image[4] == pytest.approx(1.0)
    assert int(after.best_image[1]) == 4 and int(after.candidates[0]) == 4
    assert after.candidates.max() < 9
    assert after.image[4] >= before.image[4]
    # daylight still matches its taught image
    assert int(np.argmax(idx.query(feats[7], n_states=3).image)) == 7


def test_without_experiences_nothing_changes_and_order_is_enforced() -> None:
    images = [scene(s) for s in range(6)]
    a, feats = index_of(images, [0, 0, 1, 1, 2, 2])
    b, _ = index_of(images, [0, 0, 1, 1, 2, 2])
    b.add_experiences([], [])
    q = extract(_dark(images[2]))
    x, y = a.query(q, n_states=3), b.query(q, n_states=3)
    assert np.array_equal(x.image, y.image) and np.array_equal(x.candidates, y.candidates)
    b.add_experiences([q], [2])
    with pytest.raises(ValueError, match="before any experience"):
        b.add([feats[0]], [0])
    with pytest.raises(ValueError, match="taught image"):
        b.add_experiences([q], [6])
